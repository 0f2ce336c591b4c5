"""Ground truth from the contacts of a world (`diagram.WorldDiagram`): what touches the
hand (`hand_contacts`, what a wrist force/torque sensor sums up) and the objects' states
(`object_states`: in the hand, lifted, the grasp mode, off the table)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..physics.scenes import TABLE_HEIGHT_M, VOLUME_SIZE_M


@dataclass
class ObjectState:
    name: str
    X_task_object: np.ndarray  # 4x4
    mass_kg: float
    height_above_table_m: float  # lowest collision vertex above the table top
    in_hand: bool  # touches both fingers
    lifted: bool  # in the hand and >= 1 cm above the table
    out_of_workspace: bool  # outside the task cube's footprint, or below the table top
    grasp_mode: str = ""  # in the hand: "power" (palm or proximal links touch it) or "precision"


def hand_contacts(model, plant_context) -> list:
    """(hand geometry id value, other geometry id value, force on the hand [3] N)
    per contact between the hand and something else."""
    results = model.plant.get_contact_results_output_port().Eval(plant_context)
    hand_g = model.hand_geometries
    out = []
    for i in range(results.num_hydroelastic_contacts()):
        info = results.hydroelastic_contact_info(i)
        surf = info.contact_surface()
        f_M = info.F_Ac_W().translational()  # on the body of geometry M
        m, n = surf.id_M().get_value(), surf.id_N().get_value()
        if m in hand_g and n not in hand_g:
            out.append((m, n, f_M))
        elif n in hand_g and m not in hand_g:
            out.append((n, m, -f_M))
    hand_bodies = model.hand_bodies
    for i in range(results.num_point_pair_contacts()):
        info = results.point_pair_contact_info(i)
        a_in, b_in = info.bodyA_index() in hand_bodies, info.bodyB_index() in hand_bodies
        f_B = info.contact_force()  # on body B
        pp = info.point_pair()
        if b_in and not a_in:
            out.append((pp.id_B.get_value(), pp.id_A.get_value(), f_B))
        elif a_in and not b_in:
            out.append((pp.id_A.get_value(), pp.id_B.get_value(), -f_B))
    return out


def hand_touches(model, plant_context) -> list:
    """hand_contacts by body name: (hand link, the other body, force on the hand [3] N)."""
    inspector = model.scene_graph.model_inspector()
    body_of = {}
    for g in inspector.GetAllGeometryIds():
        body = model.plant.GetBodyFromFrameId(inspector.GetFrameId(g))
        body_of[g.get_value()] = body.name() if body is not None else inspector.GetName(g)
    return [(body_of[h], body_of[o], f) for h, o, f in hand_contacts(model, plant_context)]


def _hand_contact_pairs(model, plant_context):
    """(hand geometry id value, other geometry id value) of every hand contact."""
    results = model.plant.get_contact_results_output_port().Eval(plant_context)
    hand_g = model.hand_geometries
    pairs = []
    for i in range(results.num_hydroelastic_contacts()):
        surf = results.hydroelastic_contact_info(i).contact_surface()
        m, n = surf.id_M().get_value(), surf.id_N().get_value()
        for a, b in ((m, n), (n, m)):
            if a in hand_g and b not in hand_g:
                pairs.append((a, b))
    for i in range(results.num_point_pair_contacts()):
        pp = results.point_pair_contact_info(i).point_pair()
        ga, gb = pp.id_A.get_value(), pp.id_B.get_value()
        for a, b in ((ga, gb), (gb, ga)):
            if a in hand_g and b not in hand_g:
                pairs.append((a, b))
    return pairs


def object_states(model, plant_context, names, removed, hull_vertices) -> list:
    """ObjectState of every object in `names` (in the order of model.object_bodies) but
    the `removed` ones; `hull_vertices`: name -> its collision hull's vertices (object frame)."""
    plant, pc = model.plant, plant_context
    poses = {n: plant.EvalBodyPoseInWorld(pc, b).GetAsMatrix4() for n, b in zip(names, model.object_bodies)}
    touching = {}
    geom_owner = {}
    for n, b in zip(names, model.object_bodies):
        for g in plant.GetCollisionGeometriesForBody(b):
            geom_owner[g.get_value()] = n
    inner = set(model.hand_spec.inner_links)  # as grasp_simulation's modes
    wrapped = set()
    for h, other in _hand_contact_pairs(model, pc):
        n = geom_owner.get(other)
        if n is not None:
            touching.setdefault(n, set()).add(model.finger_side_of.get(h, "palm"))
            if model.hand_link_of.get(h) in inner:
                wrapped.add(n)
    out = []
    for n, b in zip(names, model.object_bodies):
        if n in removed:
            continue
        X = poses[n]
        v = hull_vertices[n] @ X[:3, :3].T + X[:3, 3]
        height = float(v[:, 2].min() - TABLE_HEIGHT_M)
        in_hand = {"left", "right"} <= touching.get(n, set())
        c = v.mean(0)
        out_ws = bool(c[0] < 0 or c[0] > VOLUME_SIZE_M or c[1] < 0 or c[1] > VOLUME_SIZE_M
                      or v[:, 2].max() < TABLE_HEIGHT_M)
        mode = ("power" if n in wrapped else "precision") if in_hand else ""
        out.append(ObjectState(n, X, float(b.get_mass(pc)), height, in_hand,
                               in_hand and height >= 0.01, out_ws, mode))
    return out


def finger_squeeze_n(model, plant_context, closing_axis) -> tuple:
    """(left, right) [N]: how hard each finger presses on what it touches, along the
    closing axis (unit vector, task frame): the grip force the fingers exert now."""
    axis = np.asarray(closing_axis, float)
    out = {"left": 0.0, "right": 0.0}
    for h, _, force in hand_contacts(model, plant_context):
        side = model.finger_side_of.get(h)
        if side is not None:
            out[side] += abs(float(force @ axis))
    return out["left"], out["right"]
