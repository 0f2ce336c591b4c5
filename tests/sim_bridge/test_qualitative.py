"""The paper's qualitative check (sim_bridge/benchmark/qualitative.py, `make qualitative`).

The scene must reach the TSDF where the paper puts it (surfaces at the cylinder and the
box, nothing else above the table), the plotted outputs must be the detector's, and the
command must write readable PNGs, or say in one line that the model is missing.
"""
import numpy as np
import pytest
import torch
from PIL import Image

from gravgrasp_detector.perception import model_file, networks, tsdf
from sim_bridge.benchmark import qualitative


def _distance_to_cylinder_m(p):
    # Ø65 x 200 mm at scene [-0.0325, 0, 0] (base centre), p in scene coordinates
    radial = np.maximum(np.hypot(p[..., 0] + 0.0325, p[..., 1]) - 0.0325, 0.0)
    vertical = np.maximum(np.abs(p[..., 2] - 0.100) - 0.100, 0.0)
    return np.hypot(radial, vertical)


def _distance_to_box_m(p):
    # 100 x 80 x 100 mm at scene [0.06, 0, 0] (base centre)
    outside = np.maximum(np.abs(p - [0.06, 0.0, 0.05]) - [0.05, 0.04, 0.05], 0.0)
    return np.linalg.norm(outside, axis=-1)


@pytest.fixture(scope="module")
def fused():
    volume = tsdf.TSDFVolume()
    qualitative.render_scene(volume)
    grid = volume.grid()
    centres_scene = (np.indices(grid.shape).transpose(1, 2, 3, 0) + 0.5) * volume.voxel_size_m \
        - qualitative.SCENE_ORIGIN_TASK_M
    return volume, grid, centres_scene


def test_tsdf_has_surfaces_at_the_cylinder_and_the_box_and_nowhere_else_above_the_table(fused):
    volume, grid, p = fused
    vs = volume.voxel_size_m
    above_table = p[..., 2] > 1.5 * vs
    to_cylinder, to_box = _distance_to_cylinder_m(p), _distance_to_box_m(p)
    surface = above_table & (grid > 0) & (np.abs(grid - 0.5) < 0.125)  # within a voxel of the zero crossing
    assert (surface & (to_cylinder < vs)).sum() > 100
    assert (surface & (to_box < vs)).sum() > 100
    stray = surface & (np.minimum(to_cylinder, to_box) > vs)
    assert stray.sum() == 0, f"surface voxels away from both objects at scene {p[stray][:5]}"
    # Behind-surface values only reach the 3 cm truncation band behind the objects.
    behind = above_table & (grid > 0) & (grid <= 0.5)
    assert np.minimum(to_cylinder, to_box)[behind].max() <= volume.truncation_m


def test_slices_sit_at_the_papers_planes():
    vs, res = 0.0075, 40
    # heights above the table: task z = 0.05 + h
    assert qualitative.slice_layer("z", 0.15, vs, res) == (26, pytest.approx(0.14875))
    assert qualitative.slice_layer("z", 0.08, vs, res) == (17, pytest.approx(0.08125))
    assert qualitative.slice_layer("y", 0.0, vs, res) == (20, pytest.approx(0.00375))
    # At 15 cm only the 20 cm cylinder is cut: a circle of radius 32.5 mm around scene (-0.0325, 0).
    (name, lines), = qualitative.cross_sections("z", 0.14875)
    ring = np.concatenate(lines)
    assert name == "cylinder"
    assert np.hypot(ring[:, 0] + 0.0325, ring[:, 1]) == pytest.approx(0.0325, abs=2e-4)


def test_plotted_outputs_are_the_detectors(fused):
    _, grid, _ = fused
    torch.manual_seed(3)
    model = networks.GraspNet().eval()
    out = qualitative.output_volumes(model, grid)
    with torch.inference_mode():  # the path detection.detect_grasps takes
        half = model.half_features(torch.as_tensor(grid)[None, None])
        score_n, logit = model.score_and_validness_from_half(half)
    np.testing.assert_allclose(out["score_n"], score_n[0].numpy(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(out["validness"], torch.sigmoid(logit[0]).numpy(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(out["approach"], axis=-1), 1.0, atol=1e-5)


def test_command_writes_the_slice_pngs(tmp_path):
    model_path = tmp_path / "untrained.pt"
    torch.manual_seed(0)
    model_file.save_model(model_path, networks.GraspNet(), tsdf.TSDFVolume())
    assert qualitative.main(["--model", str(model_path), "--out", str(tmp_path / "out")]) == 0
    width, height = (round(s * qualitative.DPI) for s in qualitative.FIG_SIZE_IN)
    for name in ("slice_z150mm.png", "slice_z080mm.png", "slice_y000mm.png"):
        with Image.open(tmp_path / "out" / name) as image:
            assert image.size == (width, height)
            assert np.asarray(image.convert("L")).std() > 10  # not a blank canvas
    assert (tmp_path / "out" / "depth.png").stat().st_size > 10_000
    with np.load(tmp_path / "out" / "volumes.npz") as z:
        assert z["score_n"].shape == (40, 40, 40) and z["approach"].shape == (40, 40, 40, 3)


def test_missing_model_is_one_clear_line(tmp_path, capsys):
    assert qualitative.main(["--model", str(tmp_path / "gravgrasp.pt"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "gravgrasp.pt does not exist" in err[0]
    assert not (tmp_path / "out").exists()
