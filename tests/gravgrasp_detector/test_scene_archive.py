"""Scene archive: packing scene files into one file for a training machine and back
gives the same training examples (TSDF within float16 rounding) and the same split."""
import lzma

import numpy as np
import pytest

from gravgrasp_detector.training import scene_archive, scenes as training_scenes
from gravgrasp_detector.training.config import TrainConfig

from box_scenes import write_scenes


def test_pack_then_unpack_gives_the_same_training_scenes(tmp_path):
    (tmp_path / "scenes").mkdir()
    scenes = write_scenes(tmp_path / "scenes", 6, seed=3)
    archive = tmp_path / "scenes.npz.xz"
    assert scene_archive.main(["pack", str(scenes), str(archive)]) == 0
    assert scene_archive.main(["unpack", str(archive), str(tmp_path / "copy")]) == 0
    originals = sorted(p.relative_to(scenes) for p in scenes.rglob("*.npz"))
    assert sorted(p.relative_to(tmp_path / "copy") for p in (tmp_path / "copy").rglob("*.npz")) == originals
    config = TrainConfig(data="", out="")
    for name in originals:
        a = training_scenes.load_scene(scenes / name)
        b = training_scenes.load_scene(tmp_path / "copy" / name)
        assert len(a["score"]) > 0 and len(a["negative_index"]) > 0
        np.testing.assert_allclose(b["tsdf"], a["tsdf"], atol=5e-4)
        assert np.abs(b["tsdf"] - a["tsdf"]).max() > 0  # float16 in transit, as documented
        for key in ("index", "score", "e_x", "e_z", "mode", "negative_index"):
            np.testing.assert_array_equal(b[key], a[key])
        assert b["mode_names"] == a["mode_names"]
        ea, eb = (training_scenes.make_example(s, config, np.random.default_rng(1)) for s in (a, b))
        for key in ("index", "valid", "score", "R"):
            np.testing.assert_array_equal(eb[key].numpy(), ea[key].numpy())


def test_a_broken_archive_or_an_empty_directory_is_one_clear_error(tmp_path, capsys):
    (tmp_path / "bad.npz.xz").write_bytes(lzma.compress(b"not an npz"))
    assert scene_archive.main(["unpack", str(tmp_path / "bad.npz.xz"), str(tmp_path / "out")]) == 2
    assert "not a scene archive" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    with pytest.raises(training_scenes.DataError, match="no scene files"):
        scene_archive.pack(tmp_path / "empty", tmp_path / "x.npz.xz")


def test_a_training_machine_without_open3d_unpacks_trains_and_writes_a_model(tmp_path):
    # As on the GPU box: the archive, the training code, no Open3D (its import blocked).
    import subprocess
    import sys

    from gravgrasp_detector.perception import model_file, tsdf

    (tmp_path / "scenes").mkdir()
    scene_archive.pack(write_scenes(tmp_path / "scenes", 4, seed=5), tmp_path / "a.npz.xz")
    script = (
        "import sys; sys.modules['open3d'] = None\n"
        "from gravgrasp_detector.training import scene_archive, cli as training\n"
        f"scene_archive.unpack({str(tmp_path / 'a.npz.xz')!r}, {str(tmp_path / 'copy')!r})\n"
        f"sys.exit(training.main(['--data', {str(tmp_path / 'copy')!r}, '--out', {str(tmp_path / 'run')!r},"
        " '--epochs', '1', '--batch-size', '2', '--threads', '1', '--no-progress']))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    _, meta = model_file.load_model(tmp_path / "run" / "model.pt")
    assert meta["tsdf"] == model_file.tsdf_metadata(tsdf.TSDFVolume())
    assert meta["training_data"]["scenes_train"] + meta["training_data"]["scenes_val"] == 4
