"""Model files: round trip, and one clear error per way a file can be unusable."""
import pytest
import torch

from gravgrasp_detector.perception import model_file, networks
from gravgrasp_detector.perception.model_file import ModelFileError
from gravgrasp_detector.perception.tsdf import TSDFVolume


@pytest.mark.parametrize("representation", ["ex-ez", "ey-ez", "quat"])
def test_round_trip_keeps_weights_and_metadata(tmp_path, representation):
    torch.manual_seed(0)
    net = networks.GraspNet(representation, score_scale_n=10.0)
    path = tmp_path / "m.pt"
    model_file.save_model(path, net, TSDFVolume(), training_data={"scenes": 0, "note": "untrained"})
    loaded, meta = model_file.load_model(path)
    assert meta["network"]["rotation_representation"] == representation
    assert meta["tsdf"]["resolution"] == 40 and meta["tsdf"]["voxel_size_m"] == pytest.approx(0.0075)
    assert meta["training_data"]["note"] == "untrained"
    x = torch.rand(1, 1, 40, 40, 40)
    with torch.inference_mode():
        a, b = net.eval()(x), loaded(x)
    for key in a:
        torch.testing.assert_close(a[key], b[key])
    model_file.check_volume(meta, 40, 0.0075, 0.03)  # the same TSDF passes


def test_missing_file(tmp_path):
    with pytest.raises(ModelFileError, match="does not exist: train a model"):
        model_file.load_model(tmp_path / "nope.pt")


def test_corrupt_file(tmp_path):
    path = tmp_path / "bad.pt"
    path.write_bytes(b"\x00garbage" * 100)
    with pytest.raises(ModelFileError, match="cannot be read .*corrupt"):
        model_file.load_model(path)


def test_truncated_file(tmp_path):
    path = tmp_path / "m.pt"
    model_file.save_model(path, networks.GraspNet(), TSDFVolume())
    path.write_bytes(path.read_bytes()[:5000])
    with pytest.raises(ModelFileError, match="cannot be read"):
        model_file.load_model(path)


def test_plain_state_dict_is_not_a_model_file(tmp_path):
    path = tmp_path / "sd.pt"
    torch.save(networks.GraspNet().state_dict(), path)
    with pytest.raises(ModelFileError, match="not a gravgrasp model file"):
        model_file.load_model(path)


def test_weights_not_matching_metadata(tmp_path):
    path = tmp_path / "m.pt"
    model_file.save_model(path, networks.GraspNet("quat"), TSDFVolume())
    payload = torch.load(path, weights_only=True)
    payload["metadata"]["network"]["rotation_representation"] = "ex-ez"  # 6 channels, weights have 4
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match="weights do not match its metadata"):
        model_file.load_model(path)


def test_volume_mismatch_says_what_to_change(tmp_path):
    path = tmp_path / "m.pt"
    model_file.save_model(path, networks.GraspNet(), TSDFVolume())
    _, meta = model_file.load_model(path)
    with pytest.raises(ModelFileError) as e:
        model_file.check_volume(meta, 40, 0.01, 0.04)
    message = str(e.value)
    assert "voxel size 0.01 m (model: 0.0075 m)" in message
    assert "truncation 0.04 m (model: 0.03 m)" in message
    assert "resolution" not in message.split(";")[0]  # only what differs is listed
    assert "size_m=0.3" in message


def test_paths_are_stored_relative_to_the_project_or_not_at_all(tmp_path, monkeypatch):
    """Model files travel: no absolute path of the training machine goes in, and files
    written before that rule (the shipped models carry `cwd` and an absolute `data`)
    are made portable when loaded."""
    monkeypatch.chdir(tmp_path)
    summary = {"data": str(tmp_path / "out" / "scenes"), "cwd": str(tmp_path), "argv": ["--data", "/elsewhere/x"],
               "command": f"train --data {tmp_path}/out/scenes", "config": {"data": "out/scenes"}}
    model_file.save_model(tmp_path / "m.pt", networks.GraspNet(), TSDFVolume(), training_data=summary)
    stored = torch.load(tmp_path / "m.pt", weights_only=True)["metadata"]["training_data"]
    assert stored == {"data": "out/scenes", "argv": ["--data", None], "command": "train --data out/scenes",
                      "config": {"data": "out/scenes"}}

    # An old file, as `train` wrote it before: absolute paths under its recorded cwd.
    payload = torch.load(tmp_path / "m.pt", weights_only=True)
    payload["metadata"]["training_data"] = {"data": "/work/main/out/scenes_v1", "cwd": "/work/main", "epochs": 20}
    torch.save(payload, tmp_path / "old.pt")
    _, meta = model_file.load_model(tmp_path / "old.pt")
    assert meta["training_data"] == {"data": "out/scenes_v1", "epochs": 20}
    assert "/work" not in repr(meta)


def test_detect_startup_says_one_short_fact_per_line():
    import pathlib

    from gravgrasp_detector.ros.detect_node import startup_lines

    shipped = pathlib.Path(__file__).resolve().parents[2] / "models" / "gravgrasp.pt"
    _, meta = model_file.load_model(shipped)
    lines = startup_lines(str(shipped), meta, "bf16", 1)
    assert lines[0] == "model: models/gravgrasp.pt" or lines[0] == f"model: {shipped}"
    data = meta["training_data"]["data"]  # relative, as model files store paths
    assert data.startswith("out/scenes_v")
    assert any(line.startswith("model trained: ") and f"scenes from {data}," in line for line in lines), lines
    assert all(len(line) <= 80 and "{" not in line for line in lines), lines
    assert not any("/work/" in line for line in lines[1:]), lines


def test_ranking_follows_the_model():
    import pathlib

    from gravgrasp_detector.ros.detect_node import startup_lines

    score_model = {"training_data": {"target": "gravity-score"}}
    binary_model = {"training_data": {"target": "binary"}}
    assert model_file.ranking(score_model) == "score" and model_file.ranking(binary_model) == "validness"
    shipped = pathlib.Path(__file__).resolve().parents[2] / "models" / "gravgrasp.pt"
    _, meta = model_file.load_model(shipped)
    assert not any("ranked" in line for line in startup_lines(str(shipped), meta, "fp32", 1))
    binary = {**meta, "training_data": {**meta["training_data"], "target": "binary"}}
    assert "grasps ranked by validness (a binary model: no score in N, it publishes NaN)" in \
        startup_lines(str(shipped), binary, "fp32", 1)
    assert model_file.has_score(score_model) and model_file.has_score({}) and not model_file.has_score(binary_model)
