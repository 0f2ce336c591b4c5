"""The installed `evaluate_grasp` command as a real process (what `ros2 run` starts)."""

import re
import subprocess

import pytest

import ros_testing

pytestmark = pytest.mark.drake


def run(*args, timeout_s=120):
    exe = ros_testing.executable("sim_bridge", "evaluate_grasp")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=timeout_s)


def test_evaluate_grasp_prints_mode_and_six_scores_and_saves_a_picture(tmp_path):
    png = tmp_path / "grasp.png"
    r = run("--object", "box:0.04x0.05x0.06", "--mass-kg", "0.3", "--pose=0,0,-0.005,0,0,0",
            "--image", str(png))
    assert r.returncode == 0, r.stderr
    assert "mode: precision" in r.stdout
    scores = re.findall(r"score ([+-][xyz]):\s+([\d.]+) N", r.stdout)
    assert [d for d, _ in scores] == ["+x", "-x", "+y", "-y", "+z", "-z"]
    assert all(float(v) > 10 for _, v in scores)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_bad_object_is_one_clear_line():
    r = run("--object", "cylinder:0.065x0", "--mass-kg", "0.5")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0
    assert "must be 2 positive lengths" in r.stderr
    r = run("--object", "box:0.04x0.05x0.06", "--pose=1,2")
    assert r.returncode == 2 and "x,y,z[m],roll,pitch,yaw[deg]" in r.stderr
