"""The paper's qualitative check (Sec. V-A): `ros2 run sim_bridge qualitative --model M --out DIR`.

Scene of the paper: a Ø65 x 200 mm cylinder at [-0.0325, 0, 0] m and a
100 x 80 x 100 mm box (x, y, height) at [0.06, 0, 0] m standing on the table, one
camera at [0.5, 0, 0.5] m looking at the workspace centre on the table top.

Scene coordinates (the paper's, used on every plot axis) have their origin at the
workspace centre on the table top, axes parallel to the task frame's:
    task = scene + SCENE_ORIGIN_TASK_M = scene + (0.15, 0.15, 0.05) m,
so an object "at [x, y, 0]" has its base centre at task (0.15 + x, 0.15 + y, 0.05).
Slice heights z = 0.15 and z = 0.08 are heights above the table (task z = 0.20, 0.13),
y = 0 is the vertical plane through both objects (task y = 0.15). Each slice shows the
layer of voxel centres nearest to the plane; the title gives the exact position.

One depth image (VGN's 640x480 camera, as the training scenes) of the meshes and the
table is fused into the model's TSDF; the network runs on it and each slice is written
as one PNG with three panels: input TSDF, gravity-rejection score [N] with the valid
voxels circled and their approach directions (e_z) drawn, validness. The true object
cross-sections are outlined on every panel. Also written: depth.png (what the camera
saw) and volumes.npz (grid, score, validness, approach) for closer looks.

The rendering and plotting live here (no rclpy); it is in sim_bridge because it needs
sim_bridge's renderer and gravgrasp_detector must not depend on sim_bridge.
"""

import argparse
import pathlib
import sys

import numpy as np
import torch
import trimesh
from matplotlib import colormaps
from matplotlib.figure import Figure

from gravgrasp_detector import atomic_files
from gravgrasp_detector.perception import model_file, rotation, tsdf
from gravgrasp_detector.perception.model_file import ModelFileError
from gravgrasp_detector.perception.tsdf import CameraIntrinsics

from ..physics.depth_rendering import DepthRenderer, look_at
from ..physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M

SCENE_ORIGIN_TASK_M = np.array([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M])
# (name, kind, dims [m], base centre in scene coordinates [m])
OBJECTS = (
    ("cylinder", "cylinder", (0.065, 0.200), (-0.0325, 0.0, 0.0)),  # diameter, height
    ("box", "box", (0.100, 0.080, 0.100), (0.06, 0.0, 0.0)),  # x, y, height
)
CAMERA_SCENE_M = (0.5, 0.0, 0.5)
# (axis normal to the slice, position in scene coordinates [m]); z is height above the table
SLICES = (("z", 0.15), ("z", 0.08), ("y", 0.0))
# VGN's simulated camera, as sim_bridge.datagen.scene_dataset renders the training scenes
IMAGE_WIDTH, IMAGE_HEIGHT, FOCAL_PX = 640, 480, 540.0
FIG_SIZE_IN, DPI = (16.5, 5.2), 100  # each slice PNG is 1650 x 520 px
_AXES = "xyz"


class QualitativeError(RuntimeError):
    """Bad input to the qualitative check; the message says what to do."""


def scene_to_task(p_scene):
    return np.asarray(p_scene, np.float64) + SCENE_ORIGIN_TASK_M


def object_meshes():
    """[(name, trimesh in the task frame)] of the paper's two objects, standing on the table."""
    meshes = []
    for name, kind, dims, base in OBJECTS:
        if kind == "cylinder":
            mesh = trimesh.creation.cylinder(radius=dims[0] / 2, height=dims[1], sections=128)
        else:
            mesh = trimesh.creation.box(extents=dims)
        height = dims[-1]
        mesh.apply_translation(scene_to_task(base) + [0.0, 0.0, height / 2])
        meshes.append((name, mesh))
    return meshes


def table_mesh():
    # The same 2 m table as the training scenes: top at TABLE_HEIGHT_M.
    mesh = trimesh.creation.box((2.0, 2.0, 0.05))
    mesh.apply_translation([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
    return mesh


def render_scene(volume):
    """Render the paper's scene from its camera and fuse it into `volume`
    (a gravgrasp_detector.perception.tsdf.TSDFVolume). Returns (depth [m], T_task_camera)."""
    renderer = DepthRenderer([table_mesh()] + [m for _, m in object_meshes()])
    intrinsics = CameraIntrinsics(IMAGE_WIDTH, IMAGE_HEIGHT, FOCAL_PX, FOCAL_PX,
                                  (IMAGE_WIDTH - 1) / 2, (IMAGE_HEIGHT - 1) / 2)
    T_task_camera = look_at(scene_to_task(CAMERA_SCENE_M), SCENE_ORIGIN_TASK_M)
    depth = renderer.render(intrinsics, T_task_camera)
    volume.integrate(depth, intrinsics, T_task_camera)
    return depth, T_task_camera


def output_volumes(model, grid):
    """Dense network outputs on a (R, R, R) grid: score_n [N], validness (probability)
    and approach (R, R, R, 3), the unit e_z of the predicted TCP frame in the task frame."""
    with torch.inference_mode():
        out = model(torch.as_tensor(np.asarray(grid, np.float32))[None, None])
        R = rotation.reconstruct(model.rotation_representation, out["rotation"][0].permute(1, 2, 3, 0).float())
    return {
        "score_n": out["score_n"][0].numpy(),
        "validness": torch.sigmoid(out["validness_logit"][0]).numpy(),
        "approach": R[..., :, 2].numpy(),
    }


def slice_layer(axis, position_scene_m, voxel_size_m, resolution):
    """Index of the voxel layer whose centres are nearest the plane, and that layer's
    position in scene coordinates [m]."""
    a = _AXES.index(axis)
    task = position_scene_m + SCENE_ORIGIN_TASK_M[a]
    index = int(np.clip(np.floor(task / voxel_size_m), 0, resolution - 1))
    return index, (index + 0.5) * voxel_size_m - SCENE_ORIGIN_TASK_M[a]


def take_slice(volume, axis, index):
    """(R, R, ...) volume -> 2-D array indexed [first in-plane axis, second in-plane axis]."""
    return np.take(volume, index, axis=_AXES.index(axis))


def cross_sections(axis, position_scene_m):
    """[(name, [(n, 2) polylines in scene coordinates of the two in-plane axes])] of
    the objects cut by the plane; objects it misses are left out."""
    a = _AXES.index(axis)
    plane_axes = [k for k in range(3) if k != a]
    normal = np.eye(3)[a]
    origin = SCENE_ORIGIN_TASK_M + normal * position_scene_m
    out = []
    for name, mesh in object_meshes():
        section = mesh.section(plane_origin=origin, plane_normal=normal)
        if section is None:
            continue
        lines = [np.asarray(p)[:, plane_axes] - SCENE_ORIGIN_TASK_M[plane_axes] for p in section.discrete]
        out.append((name, lines))
    return out


def plot_slice(path, axis, position_scene_m, index, grid, outputs, voxel_size_m, validness_threshold, title):
    a = _AXES.index(axis)
    u, v = [k for k in range(3) if k != a]  # in-plane axes, plotted as (horizontal, vertical)
    res = grid.shape[0]
    lo = -SCENE_ORIGIN_TASK_M
    extent = (lo[u], lo[u] + res * voxel_size_m, lo[v], lo[v] + res * voxel_size_m)
    centres_u = lo[u] + (np.arange(res) + 0.5) * voxel_size_m
    centres_v = lo[v] + (np.arange(res) + 0.5) * voxel_size_m

    tsdf_2d = take_slice(grid, axis, index)
    score_2d = take_slice(outputs["score_n"], axis, index)
    valid_2d = take_slice(outputs["validness"], axis, index)
    approach_2d = take_slice(outputs["approach"], axis, index)
    sections = cross_sections(axis, position_scene_m)
    valid = valid_2d >= validness_threshold

    fig = Figure(figsize=FIG_SIZE_IN, dpi=DPI)  # no pyplot: no backend, no global figure list
    axes = fig.subplots(1, 3)

    def show(ax, image, cmap, vmin, vmax, label):
        # arrays are [u, v]; imshow wants rows = vertical axis
        im = ax.imshow(image.T, origin="lower", extent=extent, cmap=cmap, vmin=vmin, vmax=vmax,
                       interpolation="nearest")
        bar = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
        bar.set_label(label)
        for name, lines in sections:
            for k, line in enumerate(lines):
                ax.plot(line[:, 0], line[:, 1], color="magenta", lw=1.4,
                        label=f"true {name}" if k == 0 else None)
        if axis != "z":  # the table top in vertical slices
            ax.axhline(0.0, color="magenta", lw=1.0, ls="--", label="table top")
        ax.set_xlabel(f"{_AXES[u]} [m] (scene)")
        ax.set_ylabel(f"{_AXES[v]} [m] (scene{', above the table' if _AXES[v] == 'z' else ''})")
        ax.set_aspect("equal")
        return im

    # Input TSDF: 0 (never observed or outside the truncation band) is its own grey.
    tsdf_cmap = colormaps["RdBu"].copy()
    tsdf_cmap.set_bad("0.6")
    show(axes[0], np.ma.masked_equal(tsdf_2d, 0.0), tsdf_cmap, 0.0, 1.0,
         "TSDF value (0.5 surface, >0.5 free, <0.5 behind)")
    axes[0].set_title("input TSDF (grey: 0 = unobserved or\noutside the 3 cm band)")

    score_max = max(1.0, float(np.percentile(outputs["score_n"], 99.5)))
    show(axes[1], score_2d, "viridis", 0.0, score_max, "gravity-rejection score [N]")
    uu, vv = np.meshgrid(centres_u, centres_v, indexing="ij")
    axes[1].scatter(uu[valid], vv[valid], s=14, facecolors="none", edgecolors="black", linewidths=0.7,
                    label=f"validness ≥ {validness_threshold:g}")
    # Approach e_z projected on the slice: full length = in the plane, a dot = across it.
    axes[1].quiver(uu[valid], vv[valid], approach_2d[..., u][valid], approach_2d[..., v][valid],
                   color="white", angles="xy", scale_units="xy", scale=1.0 / (0.9 * voxel_size_m),
                   width=0.004, headwidth=3, headlength=3, headaxislength=2.5, pivot="tail")
    axes[1].set_title(f"score, {score_2d.min():.2f}–{score_2d.max():.2f} N here; circles: {int(valid.sum())} "
                      "valid voxels,\nwhite: their approach direction e_z projected on the slice")
    axes[1].legend(loc="upper right", fontsize=7, framealpha=0.8)

    show(axes[2], valid_2d, "Greys", 0.0, 1.0, "grasp validness (probability)")
    if 0.0 < valid_2d.min() < validness_threshold < valid_2d.max():
        axes[2].contour(centres_u, centres_v, valid_2d.T, levels=[validness_threshold], colors="tab:orange",
                        linewidths=1.2)
    axes[2].set_title(f"validness, {valid_2d.min():.3f}–{valid_2d.max():.3f} here\n"
                      f"(orange line: threshold {validness_threshold:g})")

    fig.suptitle(title, fontsize=11)
    _save_atomically(fig, path)


def plot_depth(path, depth):
    fig = Figure(figsize=(6.4, 4.8), dpi=DPI)
    ax = fig.subplots()
    im = ax.imshow(np.ma.masked_equal(depth, 0.0), cmap="viridis")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03).set_label("depth [m]")
    ax.set_title(f"depth image, camera at scene {tuple(CAMERA_SCENE_M)} m\nlooking at the table centre",
                 fontsize=10)
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    _save_atomically(fig, path)


def _save_atomically(fig, path):
    fig.tight_layout()
    atomic_files.save_figure(path, fig, dpi=DPI)


def slice_file_name(axis, position_scene_m):
    return f"slice_{axis}{position_scene_m * 1000:03.0f}mm.png"  # slice_z150mm.png


def run(model_path, out_dir, validness_threshold=0.5):
    """Render, fuse, run the model, write the PNGs; returns their paths."""
    model, metadata = model_file.load_model(model_path)
    t = metadata["tsdf"]
    if abs(float(t.get("size_m", VOLUME_SIZE_M)) - VOLUME_SIZE_M) > 1e-6:
        raise QualitativeError(f"model {model_path} expects a {t['size_m']} m volume; the paper's scene "
                               f"is laid out in the {VOLUME_SIZE_M} m workspace")
    volume = tsdf.TSDFVolume(size_m=VOLUME_SIZE_M, resolution=int(t["resolution"]),
                             truncation_voxels=round(t["truncation_m"] / t["voxel_size_m"]))
    model_file.check_volume(metadata, volume.resolution, volume.voxel_size_m, volume.truncation_m)
    depth, _ = render_scene(volume)
    grid = volume.grid()
    outputs = output_volumes(model, grid)

    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = pathlib.Path(model_path).name
    rotation_name = metadata["network"].get("rotation_representation", "?")
    target = metadata.get("training_data", {}).get("target", "?")
    paths = []
    for axis, position in SLICES:
        index, layer = slice_layer(axis, position, volume.voxel_size_m, volume.resolution)
        where = "above the table" if axis == "z" else "in scene coordinates"
        title = (f"{name} ({rotation_name}, target {target}) — slice {axis} = {position:.2f} m {where}: "
                 f"voxel layer {'ijk'[_AXES.index(axis)]} = {index}, centres at {axis} = {layer * 1000:+.2f} mm "
                 f"(task {axis} = {(layer + SCENE_ORIGIN_TASK_M[_AXES.index(axis)]):.4f} m)")
        path = out_dir / slice_file_name(axis, position)
        plot_slice(path, axis, position, index, grid, outputs, volume.voxel_size_m, validness_threshold, title)
        paths.append(path)
    depth_path = out_dir / "depth.png"
    plot_depth(depth_path, depth)
    paths.append(depth_path)
    np.savez_compressed(out_dir / "volumes.npz", tsdf=grid, **outputs,
                        scene_origin_task_m=SCENE_ORIGIN_TASK_M, voxel_size_m=volume.voxel_size_m)
    return paths


def main(argv=None):
    p = argparse.ArgumentParser(prog="qualitative", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, help="model file (.pt), e.g. models/gravgrasp.pt")
    p.add_argument("--out", required=True, help="directory for the PNGs (created)")
    p.add_argument("--validness-threshold", type=float, default=0.5,
                   help="voxels at or above this validness are circled (detect's default: 0.5)")
    args = p.parse_args(argv)
    if not 0.0 <= args.validness_threshold <= 1.0:
        print(f"qualitative: --validness-threshold {args.validness_threshold} is not in [0, 1]", file=sys.stderr)
        return 2
    try:
        paths = run(args.model, args.out, args.validness_threshold)
    except (ModelFileError, QualitativeError) as err:
        print(f"qualitative: {err}", file=sys.stderr)
        return 2
    for path in paths:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
