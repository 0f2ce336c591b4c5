"""The soak asks /execute_grasp, as the demo does, for the best-ranked grasp the executor
accepts: one refused before moving (hand in collision, unreachable) sends the next, so the
arm and the gripper run in each attempt (with v4 the top grasp of the soak's scene is
refused: asking for it alone never moved the arm)."""
from gravgrasp_msgs.msg import Grasp, GraspArray
from gravgrasp_msgs.srv import ExecuteGrasp

from sim_bridge.ros.soak import execute_best_accepted, result_name

R = ExecuteGrasp.Response


class ScriptedExecutor:
    """Stands in for Replay: /grasps as received, and /execute_grasp answering from a script."""

    def __init__(self, n_grasps, answers):
        self.latest_grasps = None
        if n_grasps is not None:
            self.latest_grasps = GraspArray(grasps=[Grasp(gravity_rejection_score=float(50 - i)) for i in range(n_grasps)])
            self.latest_grasps.header.frame_id = "task"
        self.answers, self.asked = list(answers), []

    def call(self, srv_type, name, request, timeout_s):
        assert srv_type is ExecuteGrasp and name == "execute_grasp" and not request.use_index
        assert request.header.frame_id == "task"  # the array's frame travels with each grasp
        self.asked.append(request.grasp.gravity_rejection_score)
        code = self.answers.pop(0)
        return None if code is None else R(result_code=code, message="scripted")


def test_refused_grasps_send_the_next_ranked_one_until_one_is_executed():
    ex = ScriptedExecutor(4, [R.IN_COLLISION, R.UNREACHABLE, R.SUCCESS])
    response, rank, refused = execute_best_accepted(ex)
    assert (result_name(response), rank, refused) == ("SUCCESS", 2, 2)
    assert ex.asked == [50.0, 49.0, 48.0]  # in rank order, and nothing after the executed one


def test_a_failure_after_moving_ends_the_attempt():
    ex = ScriptedExecutor(3, [R.DROPPED])
    response, rank, refused = execute_best_accepted(ex)
    assert (result_name(response), rank, refused) == ("DROPPED", 0, 0)
    assert ex.asked == [50.0]


def test_all_refused_reports_the_last_refusal():
    ex = ScriptedExecutor(2, [R.IN_COLLISION, R.IN_COLLISION])
    response, rank, refused = execute_best_accepted(ex)
    assert (result_name(response), rank, refused) == ("IN_COLLISION", 1, 1)


def test_an_unanswered_call_stops_the_walk():
    ex = ScriptedExecutor(3, [R.IN_COLLISION, None])
    response, rank, _ = execute_best_accepted(ex)
    assert response is None and rank == 1 and ex.asked == [50.0, 49.0]


def test_no_grasps_yet_asks_nothing():
    for n in (None, 0):
        ex = ScriptedExecutor(n, [])
        assert execute_best_accepted(ex) == (None, None, 0) and ex.asked == []
