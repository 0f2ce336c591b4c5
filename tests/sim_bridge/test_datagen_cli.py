import subprocess
import sys

import pytest

from sim_bridge.datagen.cli import sim_settings

pytestmark = pytest.mark.drake


def test_sim_setting_overrides_are_typed_and_validated():
    s = sim_settings(["max_close_time_s=4", "contact_model=point"])
    assert s.max_close_time_s == 4.0 and s.contact_model == "point"
    with pytest.raises(ValueError, match="KEY=VALUE"):
        sim_settings(["no_such_field=1"])
    with pytest.raises(ValueError, match="not a valid"):
        sim_settings(["time_step_s=fast"])
    with pytest.raises(ValueError):
        sim_settings(["time_step_s=1"])  # SimSettings.validate: > 0.01 s


def test_cli_without_objects_fails_with_one_line(tmp_path):
    r = subprocess.run([sys.executable, "-m", "sim_bridge.datagen", "objects", "--meshes", str(tmp_path / "nope"),
                        "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "does not exist" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "sim_bridge.datagen", "scenes", "--objects", str(tmp_path),
                        "--scenes", "1", "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "run `datagen objects` first" in (r.stdout + r.stderr)
    assert "Traceback" not in r.stderr
