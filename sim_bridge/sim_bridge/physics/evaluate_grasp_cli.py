"""`ros2 run sim_bridge evaluate_grasp`: evaluate one grasp on one object and print it.

    ros2 run sim_bridge evaluate_grasp --object cylinder:0.065x0.2 --mass-kg 0.5 \
        --pose 0,0,0.02,0,90,0 --image grasp.png

--pose is the TCP pose in the object frame: x,y,z [m], roll,pitch,yaw [deg] (fixed
axes x-y-z, Drake's RollPitchYaw). Prints the mode, contacts and the six
disturbance-rejection scores [N] along ±x, ±y, ±z of the TCP frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np
import trimesh
from pydrake.geometry import Box, Mesh
from pydrake.math import RigidTransform, RollPitchYaw

from .contact import SimSettings
from .disturbance_rejection import DIRECTION_NAMES
from .grasp_simulation import GraspSimulator
from .objects import ObjectError, parse_object_arg


def parse_pose(text: str) -> np.ndarray:
    try:
        v = [float(s) for s in text.replace(" ", ",").split(",") if s]
    except ValueError:
        v = []
    if len(v) != 6:
        raise argparse.ArgumentTypeError(f"--pose {text!r}: give x,y,z[m],roll,pitch,yaw[deg]")
    return RigidTransform(RollPitchYaw(np.radians(v[3:])), v[:3]).GetAsMatrix4()


def save_picture(sim, path: str, title: str):
    """Matplotlib drawing of the settled grasp: hand collision geometry (hulls, pads)
    and the object, in the TCP frame, seen along x and along y."""
    # lazy: matplotlib only for --image (an optional picture): its import costs seconds.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    root = sim.simulator.get_context()
    sg_ctx = sim.scene_graph.GetMyContextFromRoot(root)
    query = sim.scene_graph.get_query_output_port().Eval(sg_ctx)
    inspector = query.inspector()
    X_tcp_W = sim.X_W_tcp.inverse()
    meshes = []
    for gid, link in sim.hand.geometry_links.items():
        shape = inspector.GetShape(gid)
        if isinstance(shape, Mesh):
            m = trimesh.load(str(shape.source().path()), force="mesh")
            m.apply_scale(shape.scale3())
        elif isinstance(shape, Box):
            m = trimesh.creation.box(extents=shape.size())
        else:
            continue
        X = X_tcp_W @ query.GetPoseInWorld(gid)
        m.apply_transform(X.GetAsMatrix4())
        meshes.append((m, "#555555" if link in ("base", "base_mount") else "#3070b0"))
    pc = sim.plant.GetMyContextFromRoot(root)
    obj = sim.object.collision_mesh()
    obj.apply_transform((X_tcp_W @ sim.plant.EvalBodyPoseInWorld(pc, sim.object_body)).GetAsMatrix4())
    meshes.append((obj, "#e08030"))
    fig = plt.figure(figsize=(10, 5))
    for k, (elev, azim, name) in enumerate(((0, 0, "along x"), (0, -90, "along y"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        for m, c in meshes:
            ax.add_collection3d(Poly3DCollection(m.triangles, facecolor=c, edgecolor="none", alpha=0.6))
        ax.set_xlim(-0.1, 0.1), ax.set_ylim(-0.1, 0.1), ax.set_zlim(-0.16, 0.04)
        ax.set_box_aspect((1, 1, 1))
        ax.set_proj_type("ortho")
        ax.view_init(elev=elev, azim=azim)
        if k == 0:
            ax.set_xticks([]), ax.set_ylabel("y [m]")
        else:
            ax.set_yticks([]), ax.set_xlabel("x [m]")
        ax.set_zlabel("z (approach) [m]")
        ax.set_title(f"TCP frame, seen {name}")
    fig.suptitle(title)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="evaluate_grasp", description=__doc__.split("\n\n")[0])
    p.add_argument("--object", required=True,
                   help="box:X,Y,Z-like 'kind:AxBxC' in metres (box, cylinder, sphere, capsule, "
                        "box_with_handle) or a URDF/OBJ path")
    p.add_argument("--mass-kg", type=float)
    p.add_argument("--density-kg-m3", type=float)
    p.add_argument("--pose", type=parse_pose, default="0,0,0,0,0,0",
                   help="TCP pose in the object frame: x,y,z[m],roll,pitch,yaw[deg]")
    p.add_argument("--contact-model", choices=("hydroelastic", "point"), default="hydroelastic")
    p.add_argument("--labels", action="store_true",
                   help="label-quality settings (SimSettings.for_labels(): dt 1 ms, converged scores)")
    p.add_argument("--dt", type=float, help=f"time step [s] (default {SimSettings.time_step_s})")
    p.add_argument("--ramp-rate", type=float, help=f"N/s (default {SimSettings.force_ramp_rate_n_s})")
    p.add_argument("--grip-force", type=float, default=SimSettings.grip_force_n, help="N")
    p.add_argument("--image", help="save a picture of the settled grasp (PNG)")
    a = p.parse_args(argv)
    try:
        obj = parse_object_arg(a.object, a.mass_kg, a.density_kg_m3)
        base = SimSettings.for_labels() if a.labels else SimSettings()
        settings = dataclasses.replace(
            base, contact_model=a.contact_model, grip_force_n=a.grip_force,
            time_step_s=a.dt or base.time_step_s,
            force_ramp_rate_n_s=a.ramp_rate or base.force_ramp_rate_n_s)
        settings.validate()
    except (ObjectError, ValueError) as e:
        print(f"evaluate_grasp: {e}", file=sys.stderr)
        return 2
    sim = GraspSimulator(obj, settings)
    out = sim.evaluate(a.pose)
    print(f"object: {obj.name} mass {obj.mass_kg:.3f} kg  ({settings.contact_model}, "
          f"dt {settings.time_step_s * 1000:g} ms, ramp {settings.force_ramp_rate_n_s:g} N/s)")
    print(f"grasped: {out.grasped}  mode: {out.mode}" + (f"  ({out.reason})" if out.reason else ""))
    print(f"contacts: {out.num_contacts} on {', '.join(out.contact_links) or '-'}")
    print("finger joints [rad]: " + " ".join(f"{k}={v:.3f}" for k, v in out.finger_joint_angles.items()))
    for name, s, dep in zip(DIRECTION_NAMES, out.scores_n, out.departed):
        cap = "" if dep or not out.grasped else f"  (held to the {settings.max_force_n:.0f} N cap)"
        print(f"score {name}: {s:7.1f} N{cap}")
    print(f"min score: {out.min_score_n:.1f} N  sim {out.sim_time_s:.2f} s  wall {out.wall_time_s:.2f} s")
    if a.image:
        save_picture(sim, a.image, f"{obj.name}: {out.mode}, min {out.min_score_n:.0f} N")
        print(f"picture: {a.image}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
