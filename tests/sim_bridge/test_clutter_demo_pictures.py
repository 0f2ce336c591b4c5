"""The demo's attempt pictures show the grasp the executor executed (issue 43): when it
refuses the top-ranked grasp before moving and executes the second, the picture circles
and titles the second and crosses out the first, as report.json records. No ROS graph:
the demo's cell runs on a stand-in client; the messages are real."""
import math
import threading
import time
import types

import numpy as np
import pytest
from geometry_msgs.msg import Pose, PoseStamped
from sensor_msgs.msg import CameraInfo, Image

from gravgrasp_msgs.msg import Grasp, GraspArray, ObjectStates
from gravgrasp_msgs.srv import ExecuteGrasp
from sim_bridge.benchmark.clearing import clear_table
from sim_bridge.ros import clutter_demo

# Camera 0.5 m above the task origin looking straight down (optical z = task -z).
T_TASK_CAMERA = np.array([[1.0, 0, 0, 0.15], [0, -1.0, 0, 0.15], [0, 0, -1.0, 0.5], [0, 0, 0, 1.0]])
K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
SCORES_N = [63.1, 57.4, 40.2]
POSITIONS = [(0.10, 0.12, 0.05), (0.20, 0.18, 0.05), (0.15, 0.10, 0.04)]


def _view():
    return clutter_demo.CameraView(np.full((48, 64), 0.45), K, T_TASK_CAMERA)


def _scatter(ax, label):
    return next(c for c in ax.collections if c.get_label() == label)


def test_the_picture_circles_and_titles_the_executed_grasp_and_crosses_the_refused():
    view = _view()
    fig = clutter_demo.attempt_figure(view, POSITIONS, SCORES_N, executed=1, refused=[0], outcome="success")
    ax = fig.axes[0]
    u, v = view.pixels(POSITIONS)
    np.testing.assert_allclose(_scatter(ax, "executed").get_offsets(), [[u[1], v[1]]])
    np.testing.assert_allclose(_scatter(ax, "refused before motion").get_offsets(), [[u[0], v[0]]])
    title = ax.get_title()
    assert "executed #2: 57.4 N (success)" in title
    assert "refused before motion: #1 (63.1 N)" in title


def test_pixels_project_through_the_camera_pose():
    """A point straight below the camera lands on the principal point; 0.1 m along task +x
    at 0.45 m depth moves 100 * 0.1 / 0.45 px along u."""
    u, v = _view().pixels([(0.15, 0.15, 0.05), (0.25, 0.15, 0.05)])
    np.testing.assert_allclose(u, [32.0, 32.0 + 100 * 0.1 / 0.45])
    np.testing.assert_allclose(v, [24.0, 24.0])


def test_title_when_every_grasp_was_refused():
    assert clutter_demo.attempt_title(SCORES_N, None, [0, 1, 2]).startswith("3 grasps; none executed\nrefused")


def test_a_binary_models_picture_shows_validness_not_newtons():
    """A binary model publishes NaN scores: the title names validness, the colour bar too."""
    fig = clutter_demo.attempt_figure(_view(), POSITIONS, [math.nan] * 3, executed=1, refused=[0],
                                      outcome="success", validness=[0.97, 0.91, 0.6])
    title = fig.axes[0].get_title()
    assert "executed #2: validness 0.91 (success)" in title and "#1 (validness 0.97)" in title
    assert " N" not in title and fig.axes[1].get_ylabel() == "validness"


class _Client:
    """The demo client's surface: the sim refuses grasp #1 (hand in collision) and lifts
    the object with grasp #2."""

    def __init__(self, scores_n=SCORES_N):
        self.scores_n = scores_n
        self.states = self._states(lifted=False)
        self.modes_seen = {}
        self.sent = []
        self.depth = Image(height=48, width=64, encoding="32FC1", step=64 * 4,
                           data=np.full((48, 64), 0.45, np.float32).tobytes())
        self.info = CameraInfo(height=48, width=64, k=K.ravel().tolist())
        self.camera_pose = PoseStamped()
        p, q = self.camera_pose.pose.position, self.camera_pose.pose.orientation
        p.x, p.y, p.z = T_TASK_CAMERA[:3, 3]
        q.x, q.y, q.z, q.w = 1.0, 0.0, 0.0, 0.0  # 180 deg about x: looks down

    @staticmethod
    def _states(lifted, removed=False):
        if removed:
            return ObjectStates()
        return ObjectStates(names=["box"], poses=[Pose()], mass_kg=[1.0], lifted=[lifted],
                            out_of_workspace=[False], grasp_mode=["power" if lifted else ""])

    def fresh_grasps(self, timeout_s):
        msg = GraspArray()
        for (x, y, z), s, v in zip(POSITIONS, self.scores_n, (0.97, 0.9, 0.6)):
            g = Grasp(gravity_rejection_score=s, validness=v)
            g.pose.position.x, g.pose.position.y, g.pose.position.z = x, y, z
            g.pose.orientation.w = 1.0
            msg.grasps.append(g)
        return msg

    def call(self, srv_type, name, request, timeout_s):
        self.sent.append(name)
        if name == "execute_grasp":
            if request.grasp.validness == pytest.approx(0.97):  # the top-ranked grasp
                return ExecuteGrasp.Response(result_code=ExecuteGrasp.Response.IN_COLLISION,
                                             message="hand in collision at pre-grasp")
            self.states = self._states(lifted=True)
            return ExecuteGrasp.Response(success=True, result_code=ExecuteGrasp.Response.SUCCESS, message="held")
        if name == "remove_object":
            self.states = self._states(lifted=False, removed=True)
        return srv_type.Response()

    def states_after(self, delay_s, timeout_s=30.0):
        return self.states


def test_the_demo_draws_and_reports_the_executed_grasp_not_the_top_ranked(tmp_path, monkeypatch):
    drawn = []

    def record(view, positions, scores, executed, refused, outcome="", **kw):
        drawn.append((executed, list(refused), outcome))
        return real(view, positions, scores, executed, refused, outcome, **kw)

    real = clutter_demo.attempt_figure
    monkeypatch.setattr(clutter_demo, "attempt_figure", record)
    report = {"errors": []}
    cell = clutter_demo.DemoCell(_Client(), types.SimpleNamespace(mass_kg=1.0), tmp_path, report)
    record_ = clear_table(cell, n_objects=1)
    assert record_["end"] == "table_clear"
    (attempt,) = record_["attempts"]
    assert attempt["rank"] == 1 and attempt["score_n"] == pytest.approx(57.4, abs=1e-4)
    assert [r["rank"] for r in attempt["refused"]] == [0]
    assert attempt["refused"][0]["score_n"] == pytest.approx(63.1, abs=1e-4)
    assert drawn == [(1, [0], "success")]
    assert (tmp_path / "attempt_01.png").stat().st_size > 0


def test_a_binary_models_attempt_reports_and_prints_validness(tmp_path, capsys):
    """score_n None in report.json (strict JSON, no probability under a newton's name), and
    the attempt line names the validness, not newtons."""
    report = {"errors": []}
    cell = clutter_demo.DemoCell(_Client([math.nan] * 3), types.SimpleNamespace(mass_kg=1.0), tmp_path, report)
    (attempt,) = clear_table(cell, n_objects=1)["attempts"]
    assert attempt["score_n"] is None and attempt["validness"] == pytest.approx(0.9)
    assert attempt["all_scores_n"] == [None] * 3 and attempt["all_validness"] == pytest.approx([0.97, 0.9, 0.6])
    assert attempt["refused"][0]["score_n"] is None and attempt["refused"][0]["validness"] == pytest.approx(0.97)
    line = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("attempt 1:"))
    assert "validness 0.90 (no score in N)" in line and "score" not in line.replace("no score in N", ""), line
    clutter_demo.save_summary_png({**report, "attempts": [{**attempt, "success": True}], "seed": 1, "SR": 1.0,
                                   "CR": 1.0, "n_objects": 1, "object_mass_kg": 1.0}, tmp_path / "summary.png")
    assert (tmp_path / "summary.png").stat().st_size > 0


def test_the_summary_page_plots_a_score_models_newtons(tmp_path):
    report = {"errors": []}
    cell = clutter_demo.DemoCell(_Client(), types.SimpleNamespace(mass_kg=1.0), tmp_path, report)
    attempts = clear_table(cell, n_objects=1)["attempts"]
    clutter_demo.save_summary_png({"errors": [], "attempts": attempts, "seed": 1, "SR": 1.0, "CR": 1.0, "n_objects": 1,
                                   "object_mass_kg": 1.0, "min_score_n": 14.7, "safety": 1.5}, tmp_path / "summary.png")
    assert (tmp_path / "summary.png").stat().st_size > 0


def test_the_first_attempt_gets_its_picture_when_the_camera_is_heard_late(tmp_path):
    """The demo's first detection came before its client had heard the camera, and
    attempt_01.png was silently not drawn: the cell waits for the camera (here 0.3 s)."""
    client = _Client()
    heard = (client.depth, client.info, client.camera_pose)
    client.depth = client.info = client.camera_pose = None

    def hear():
        time.sleep(0.3)
        client.depth, client.info, client.camera_pose = heard
    threading.Thread(target=hear, daemon=True).start()
    cell = clutter_demo.DemoCell(client, types.SimpleNamespace(mass_kg=1.0), tmp_path, {"errors": []})
    assert clear_table(cell, n_objects=1)["end"] == "table_clear"
    assert (tmp_path / "attempt_01.png").stat().st_size > 0
