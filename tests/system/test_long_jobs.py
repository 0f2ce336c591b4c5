"""The long-job scripts: `ros_ws/run_pinned.sh` runs a job on one commit's code, so that
editing the working tree while data generation or training runs for hours cannot change
it; the dataset chains it starts must at least parse."""
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _git(repo, *args):
    return subprocess.run(["git", "-c", "user.name=test", "-c", "user.email=test@example.com", *args],
                          cwd=repo, check=True, capture_output=True, text=True).stdout.strip()


SCRIPTS = sorted(str(p.relative_to(ROOT)) for folder in ("ros_ws", "sim_bridge/chains")
                 for p in (ROOT / folder).glob("*.sh"))


def test_the_chains_are_recipes_in_chains():
    """ros_ws holds the workspace set-up only; the long-job recipes it pins live in sim_bridge/chains/,
    beside the results they write and outside the installed Python package; the top level stays as fixed."""
    assert {"sim_bridge/chains/benchmark_chain.sh", "sim_bridge/chains/dataset_v5_chain.sh"} <= set(SCRIPTS)
    assert not [s for s in SCRIPTS if s.startswith("ros_ws/") and s.endswith("_chain.sh")]
    assert not list((ROOT / "sim_bridge" / "sim_bridge").rglob("*_chain.sh"))
    assert not (ROOT / "chains").exists()


@pytest.mark.parametrize("script", SCRIPTS)
def test_scripts_parse(script):
    r = subprocess.run(["bash", "-n", str(ROOT / script)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.fixture
def repo(tmp_path):
    """A git repository with the two scripts and a module the job imports."""
    (tmp_path / "ros_ws").mkdir()
    for name in ("run_pinned.sh", "env.sh"):
        shutil.copy(ROOT / "ros_ws" / name, tmp_path / "ros_ws" / name)
    (tmp_path / "sim_bridge").mkdir()
    (tmp_path / "sim_bridge" / "pinned_probe.py").write_text('VALUE = "committed"\n')
    (tmp_path / ".gitignore").write_text("out/\n")
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "commit", "-qm", "probe")
    return tmp_path


def _wait_for(path, text, timeout_s=30.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return path.read_text()
        time.sleep(0.1)
    raise AssertionError(f"{path} never said {text!r}: {path.read_text() if path.exists() else 'missing'}")


def test_job_runs_the_pinned_commit_not_the_edited_tree(repo):
    # The job imports its module after the tree was edited; it must still see the commit's.
    job = [sys.executable, "-c", "import time; time.sleep(1.5); import pinned_probe; "
           "print('probe=' + pinned_probe.VALUE); import os; print('cwd=' + os.getcwd())"]
    r = subprocess.run(["bash", "ros_ws/run_pinned.sh", "HEAD", "out/job.log", "--", *job],
                       cwd=repo, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    commit = _git(repo, "rev-parse", "HEAD")
    assert f"on {commit[:12]}" in r.stdout
    (repo / "sim_bridge" / "pinned_probe.py").write_text('VALUE = "edited"\n')
    log = _wait_for(repo / "out" / "job.log", "cwd=")
    assert "probe=committed" in log
    assert f"cwd={repo}" in log  # relative --out paths land in the checkout, not the worktree
    assert (repo / "out" / "pinned" / commit[:12] / "sim_bridge" / "pinned_probe.py").read_text() \
        == 'VALUE = "committed"\n'

    # A rerun of the same line (the next session's resume) reuses the worktree and appends.
    r = subprocess.run(["bash", "ros_ws/run_pinned.sh", commit, "out/job.log", "--", *job],
                       cwd=repo, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    deadline = time.monotonic() + 30
    while (repo / "out" / "job.log").read_text().count("probe=committed") < 2:
        assert time.monotonic() < deadline, (repo / "out" / "job.log").read_text()
        time.sleep(0.1)


def test_usage_and_unknown_commit_are_one_clear_error(repo):
    r = subprocess.run(["bash", "ros_ws/run_pinned.sh", "HEAD", "out/job.log", "true"],
                       cwd=repo, capture_output=True, text=True)
    assert r.returncode == 2 and "usage: ros_ws/run_pinned.sh COMMIT LOG -- COMMAND" in r.stderr
    r = subprocess.run(["bash", "ros_ws/run_pinned.sh", "no-such-commit", "out/job.log", "--", "true"],
                       cwd=repo, capture_output=True, text=True)
    assert r.returncode == 2 and "'no-such-commit' names no commit" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (repo / "out" / "pinned").exists()
