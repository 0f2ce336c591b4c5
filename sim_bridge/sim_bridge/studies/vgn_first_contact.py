"""What does the Panda hand touch when the arm's contact stop halts a VGN grasp, and why
does VGN pick such a grasp? (issue 41: the first vgn rounds on the held-out scenes)

`first_view`: a round's first view rebuilt from its committed scene, protocol and model
file (as studies.first_view_picks does; the pick is trusted only when it equals
the recorded attempt 1 to 2e-6). For that pick it prints where the TCP sits against the
true surface, which hand part meets which object first along the approach (the hand's
true convex hulls, panda_hand.open_hand_hulls_tcp, against object surface samples:
pick_diagnosis.first_contact_hulls), the object's span across the closing axis at the
last 10 mm of the finger tips against the open pads at +-40 mm, then executes the pick
and prints where the arm's contact stop halted it and what Drake says touches the hand.

`centring`: where VGN's top grasp sits on a lone upright cylinder or sphere, placed at
16 sub-voxel offsets, seen by the benchmark's camera turned 0/90/180/270 deg about the
cube's vertical axis. The mean offset of the TCP from the object's axis has a part that
turns with the camera (what one view hides) and a part fixed to the grid: the mean over
the four turns.

    python -m sim_bridge.studies.vgn_first_contact --results sim_bridge/results/baselines_heldout \\
        --method vgn --weight 0.1 --scene packed_000 [--close-within-m 0.01]
    python -m sim_bridge.studies.vgn_first_contact --centring
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys

import numpy as np
import torch
import trimesh
from scipy.spatial.transform import Rotation

from gravgrasp_detector.perception.model_file import file_sha256

from ..analysis import pick_diagnosis
from ..analysis.replay import SurfaceSamples
from ..benchmark import run_files
from ..benchmark.methods import METHODS, vgn
from ..benchmark.protocol import Protocol
from ..benchmark.rounds import RoundTask, make_cell
from ..physics import panda_hand
from ..physics.depth_rendering import render_depth
from ..physics.scenes import TABLE_HEIGHT_M
from ..world import CameraSettings, camera_intrinsics, camera_pose

TIP_SPAN_M = 0.010  # the finger tips' last 10 mm: where a wide object meets an off-centre pad first
SHAPES = ("cylinder 60 mm", "sphere 60 mm", "cylinder 45 mm")
AZIMUTHS_DEG = (0, 90, 180, 270)


def across_closing_axis(q_tcp) -> tuple | None:
    """(min, max) y [m] of TCP-frame points in the pads' slab (|x| within the finger's
    half width) at the finger tips' last TIP_SPAN_M; None if none lie there."""
    q = np.asarray(q_tcp, float)
    tip = panda_hand.FINGER_DEPTH_M
    sel = (np.abs(q[:, 0]) < panda_hand.FINGER_HALF_WIDTH_X_M) & (q[:, 2] > tip - TIP_SPAN_M) & (q[:, 2] <= tip)
    return (float(q[sel, 1].min()), float(q[sel, 1].max())) if sel.any() else None


def first_view(results_dir, method: str, mass_kg: float, scene_id: str, model_path=None, close_within_m=None,
               report=print) -> dict:
    """The diagnosis of a round's first pick (module doc); `report` gets each line.
    close_within_m: execute it with the executor's guarded approach instead of the
    round's protocol (close where the contact stop halted it, if that short or less: what
    VGN's clutter-removal evaluation does at the first contact, allow_contact=True)."""
    results_dir = pathlib.Path(results_dir)
    recorded = run_files.rounds_file(results_dir).get(method, mass_kg, scene_id)
    if recorded is None:
        raise ValueError(f"{results_dir} has no round of {method} at {mass_kg:g} kg on {scene_id}")
    path = pathlib.Path(model_path) if model_path else METHODS[method].default_path()
    if file_sha256(path) != recorded["model_sha256"]:
        raise ValueError(f"{path} is not the model the round ran (sha256 {recorded['model_sha256'][:12]}…): "
                         "pass --model with that file")
    config = json.loads((results_dir / "config.json").read_text())
    scene = run_files.scenes_file(results_dir).get(scene_id)
    protocol = Protocol(**config["protocol"])
    if close_within_m is not None:
        protocol = dataclasses.replace(protocol, close_on_contact_within_m=close_within_m)
    torch.set_num_threads(1)
    cell, _ = make_cell(RoundTask(method, str(path), recorded["model_sha256"], float(mass_kg), scene, protocol))
    cell.settle()
    cell.remove_fallen()
    tsdf, grasps = cell.detect()
    grasp = grasps[recorded["attempts"][0]["rank"]]
    X = np.asarray(grasp.pose)
    same = bool(np.allclose(X, recorded["attempts"][0]["pose"], atol=2e-6))
    report(f"{method} {mass_kg} kg {scene_id}: pick at {np.round(X[:3, 3], 4).tolist()} m, approach "
           f"{np.round(X[:3, 2], 3).tolist()}, closing axis {np.round(X[:3, 1], 3).tolist()}, quality "
           f"{grasp.validness:.4f}; the recorded attempt 1: {'same' if same else 'DIFFERENT'}")
    approach_m = cell.limits.pregrasp_distance_m
    points = SurfaceSamples(cell.world, pick_diagnosis.sample_surface).now()
    contact = pick_diagnosis.first_contact_hulls(X, approach_m, panda_hand.open_hand_hulls_tcp(), points)
    out = {"same_pose": same, "first_contact": contact}
    if contact is None:
        report("approach: the open hand reaches the grasp pose touching nothing")
    else:
        q = (points[contact["what"]] - X[:3, 3]) @ X[:3, :3]
        top_mm = 1e3 * q[:, 2].min()
        span = across_closing_axis(q)
        out.update(object_top_past_tcp_m=round(float(q[:, 2].min()), 4), across_closing_m=span)
        report(f"approach: the {contact['part']} meets {contact['what']} after {1e3 * contact['approach_m']:.1f} of "
               f"{1e3 * approach_m:.0f} mm ({1e3 * contact['short_m']:.1f} mm short), at "
               f"{np.round(1e3 * np.array(contact['point_tcp_m']), 1).tolist()} mm in the grasp's TCP frame")
        report(f"  {contact['what']}: its top {top_mm:.1f} mm past the TCP (the palm face: "
               f"{1e3 * (panda_hand.PALM_FACE_Z_M - panda_hand.HAND_TO_TCP_M):.0f} mm)"
               + ("" if span is None else
                  f"; across the closing axis at the finger tips' last {1e3 * TIP_SPAN_M:.0f} mm: y "
                  f"{1e3 * span[0]:+.1f} .. {1e3 * span[1]:+.1f} mm (middle {1e3 * sum(span) / 2:+.1f}), open pads "
                  f"at +-{1e3 * panda_hand.FINGER_TRAVEL_M:.0f} mm"))
    travel, stop = cell.world.travel, {}

    def watched_travel(X_target, speed_mps, timeout_s=30.0):
        motion = travel(X_target, speed_mps, timeout_s)
        if motion.stopped_by_contact and not stop:
            tcp = cell.world.tcp_pose()
            stop.update(short_m=round(float((X[:3, 3] - tcp[:3, 3]) @ X[:3, 2]), 4),
                        touches=[(h, o, np.round(f, 1).tolist()) for h, o, f in cell.world.hand_touches()])
        return motion
    cell.world.travel = watched_travel
    result = cell.execute(grasp, tsdf)
    out.update(outcome=result["outcome"], stop=stop)
    report(f"executed: {result['outcome']}: {result['reason'][:110]}")
    if stop:
        report(f"  the arm's contact stop: the TCP {1e3 * stop['short_m']:.1f} mm short of the grasp pose; touching "
               + "; ".join(f"{h} - {o} ({f} N on the hand)" for h, o, f in stop["touches"]))
    return out


def _lone_object(shape: str, centre_xy) -> trimesh.Trimesh:
    kind, size_mm, _ = shape.split()
    d = float(size_mm) / 1000
    if kind == "cylinder":
        m = trimesh.creation.cylinder(radius=d / 2, height=0.08, sections=96)
        m.apply_translation((*centre_xy, TABLE_HEIGHT_M + 0.04))
    else:
        m = trimesh.creation.icosphere(subdivisions=4, radius=d / 2)
        m.apply_translation((*centre_xy, TABLE_HEIGHT_M + d / 2))
    return m


def centring(shapes=SHAPES, azimuths_deg=AZIMUTHS_DEG, report=print) -> dict:
    """{azimuth: mean (x, y) [m] of VGN's top TCP minus the object's axis} (module doc),
    and "grid": their mean over the azimuths."""
    torch.set_num_threads(1)
    detect = vgn.make_vgn_detector(vgn.load_vgn())
    voxel = vgn.VOXEL_SIZE_M
    camera = CameraSettings()
    K, T0 = camera_intrinsics(camera), camera_pose(camera)
    table = trimesh.creation.box((1.0, 1.0, 0.05))
    table.apply_translation((0.15, 0.15, TABLE_HEIGHT_M - 0.025))
    C = np.eye(4)
    C[:3, 3] = (0.15, 0.15, 0.0)
    means = {}
    for az in azimuths_deg:
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_euler("z", az, degrees=True).as_matrix()
        T = C @ turn @ np.linalg.inv(C) @ T0
        offsets = []
        for shape in shapes:
            for fx in np.arange(4) / 4:
                for fy in np.arange(4) / 4:
                    c = np.array([0.15 + fx * voxel, 0.15 + fy * voxel])
                    depth = render_depth([table, _lone_object(shape, c)], K, T, camera.max_depth_m)
                    volume = vgn.vgn_volume()
                    volume.integrate(depth, K, T)
                    grasps = detect((volume.grid(), volume.voxel_size_m, volume.origin))
                    if grasps:
                        offsets.append(grasps[0].pose[:2, 3] - c)
        means[az] = np.mean(offsets, axis=0)
        report(f"camera turned {az:3d} deg (at xy {np.round(T[:2, 3], 3).tolist()} m): {len(offsets)} grasps, mean TCP "
               f"minus the axis x {1e3 * means[az][0]:+.1f} y {1e3 * means[az][1]:+.1f} mm")
    means["grid"] = np.mean([means[az] for az in azimuths_deg], axis=0)
    x_mm, y_mm = 1e3 * means["grid"]
    report(f"fixed to the grid (mean over the turns): x {x_mm:+.1f} y {y_mm:+.1f} mm (voxel {1e3 * voxel:.1f} mm)")
    return means


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--results", help="a benchmark output directory, e.g. sim_bridge/results/baselines_heldout")
    p.add_argument("--method", default="vgn")
    p.add_argument("--weight", type=float, help="the round's object weight [kg]")
    p.add_argument("--scene", help="scene id, e.g. packed_000")
    p.add_argument("--model", help="the model file the round ran (default: the method's)")
    p.add_argument("--close-within-m", type=float,
                   help="execute with the guarded approach (close where the contact stop halted it, if this short)")
    p.add_argument("--centring", action="store_true", help="measure VGN's centring on lone objects instead")
    args = p.parse_args(argv)
    if args.centring:
        centring()
        return 0
    if not (args.results and args.weight and args.scene):
        p.error("give --results, --weight and --scene (a committed round), or --centring")
    try:
        first_view(args.results, args.method, args.weight, args.scene, args.model, args.close_within_m)
    except (ValueError, FileNotFoundError) as e:
        print(f"vgn_first_contact: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
