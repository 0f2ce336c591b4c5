"""The cell as one Drake diagram: plant (gravity, SAP, the paper's contact parameters),
scene graph, the table, the floating hand (the 2F-85, or another of physics.hands:
WorldSettings.hand) and its finger servo (physics.actuators.FingerServoSystem, driven as
finger_drives says), with the 2F-85's self-locking transmission when SimSettings.drive
says so (physics.transmission)."""

from __future__ import annotations

from dataclasses import dataclass

from pydrake.geometry import AddContactMaterial, AddRigidHydroelasticProperties, Box, ProximityProperties
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder

from ..physics.actuators import FingerServoSystem, driver_torque_nm
from ..physics.hands import hand_spec
from ..physics.contact import proximity_properties
from ..physics.scenes import TABLE_FRICTION, TABLE_HEIGHT_M, VOLUME_SIZE_M
from ..physics.transmission import add_transmission_lock
from .config import WorldSettings
from .finger_drives import DRIVES


@dataclass
class WorldDiagram:
    diagram: object
    plant: object
    scene_graph: object
    hand: object
    mount_body: object  # the hand's floating body (the 2F-85's base_mount, the Panda's hand link)
    object_bodies: list
    finger_servo: object
    # Geometries by GeometryId *value* (int): pydrake hands out GeometryIds that can
    # point into a vector the plant later grows (hand_model.Hand.geometry_links had
    # garbage ids, so the pad boxes were not recognised), so copy the values at once.
    hand_link_of: dict  # collision geometry id value -> hand link name
    hand_geometries: frozenset  # collision geometry id values of the hand
    finger_geometries: frozenset
    hand_bodies: frozenset  # BodyIndex of every hand link
    hand_spec: object  # physics.hands.HandSpec
    drive: object  # finger_drives.FingerDrive
    finger_side_of: dict  # finger collision geometry id value -> "left" or "right"
    # physics.transmission.TransmissionLock of a self-locking 2F-85 (SimSettings.drive);
    # None for the back-drivable drive and the Panda (its fingers are not underactuated)
    transmission_lock: object = None

    def release(self) -> None:
        """Let the garbage collector free this diagram; call only when discarding it (no
        system of it may be used after).

        pydrake (1.51) never frees a diagram that holds a Python LeafSystem: C++ keeps the
        Python system alive while the diagram lives, and the system keeps its builder and
        diagram alive through pydrake's reference-cycle bookkeeping, a cycle through C++
        that gc cannot see (+15 MB of RSS per load_scene in the sim bridge). Emptying the
        Python systems' attributes (that bookkeeping lives there) breaks it; their
        callbacks hold them only weakly (FingerServoSystem). tests/sim_bridge/test_world_memory.py
        measures that repeated resets stay flat.
        """
        for system in self.diagram.GetSystems():
            if not type(system).__module__.startswith("pydrake"):
                vars(system).clear()


def build_world_diagram(objects, settings: WorldSettings) -> WorldDiagram:
    """Plant (gravity, SAP, the paper's contact parameters) + scene graph + the finger
    servo. `objects`: list of (name, ObjectSpec). The table is a 1 m box whose top is the
    plane z = TABLE_HEIGHT_M; the hand floats (its pose is set by SimWorld each step)."""
    s = settings.contact
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=s.time_step_s, discrete_contact_approximation="sap",
        contact_model="hydroelastic_with_fallback" if s.contact_model == "hydroelastic" else "point"),
        builder)
    props = proximity_properties(s)
    table_props = ProximityProperties()
    AddContactMaterial(dissipation=s.hunt_crossley_dissipation_s_per_m,
                       friction=CoulombFriction(TABLE_FRICTION, TABLE_FRICTION), properties=table_props)
    table_props.AddProperty("material", "relaxation_time", s.effective_relaxation_time_s())
    if s.contact_model == "hydroelastic":
        AddRigidHydroelasticProperties(0.01, table_props)
    X_table = RigidTransform([VOLUME_SIZE_M / 2, VOLUME_SIZE_M / 2, TABLE_HEIGHT_M - 0.025])
    plant.RegisterCollisionGeometry(plant.world_body(), X_table, Box(1.0, 1.0, 0.05), "table", table_props)
    plant.RegisterVisualGeometry(plant.world_body(), X_table, Box(1.0, 1.0, 0.05), "table_visual",
                                 [0.6, 0.6, 0.6, 1.0])
    # No shelf for removed objects and no floor: objects out of play are taken out of the
    # physics (out_of_play).
    spec, drive = hand_spec(settings.hand), DRIVES[settings.hand]
    hand = spec.add(plant, scene_graph, props, True, s.contact_model == "point", settings.baselines_dir or None)
    bodies = [spec.add_to_plant(plant, name=name, proximity_properties=props) for name, spec in objects]
    plant.set_gravity_enabled(hand.model_instance, False)  # the arm carries the hand
    for j in hand.driver_joints:
        j.set_default_damping(drive.joint_damping)
    plant.Finalize()
    servo = builder.AddSystem(FingerServoSystem(plant, hand, s.time_step_s, drive.kp, drive.open_joint))
    builder.Connect(plant.get_state_output_port(), servo.get_input_port())
    builder.Connect(servo.get_output_port(), plant.get_actuation_input_port())
    lock = (add_transmission_lock(builder, plant, hand, s.time_step_s, driver_torque_nm(s.grip_force_n),
                                  stiffness_nm_per_rad=s.lock_stiffness_nm_per_rad,
                                  damping_nm_s_per_rad=s.lock_damping_nm_s_per_rad)
            if s.drive == "self_locking" and settings.hand == "2f85" else None)
    diagram = builder.Build()
    link_of = {}
    for bi in plant.GetBodyIndices(hand.model_instance):
        body = plant.get_body(bi)
        for g in plant.GetCollisionGeometriesForBody(body):
            link_of[g.get_value()] = body.name()
    side = {g: "left" if link in spec.left_links else "right" for g, link in link_of.items()
            if link in spec.finger_links}
    return WorldDiagram(diagram, plant, scene_graph, hand, plant.GetBodyByName(spec.mount_body, hand.model_instance),
                        bodies, servo, link_of, frozenset(link_of), frozenset(side),
                        frozenset(plant.GetBodyIndices(hand.model_instance)), spec, drive, side, lock)
