"""The sim bridge's world (sim_bridge.world) in-process: arm stand-in, fingers driven
through the robotiq FingerPlant, gravity, depth rendering, ground truth."""
import numpy as np
import pytest

from robotiq_driver.emulator.emulated_gripper import GripperEmulator
from robotiq_driver.gripper_registers import COMMAND_ADDRESS, GripperCommand, ObjectStatus
from sim_bridge.physics.contact import SimSettings
from sim_bridge.physics.objects import procedural_object
from sim_bridge.physics.scenes import TABLE_HEIGHT_M
from sim_bridge.world import R_TOP_DOWN, SceneConfig, SimFingerPlant, SimWorld, WorldSettings, pose

pytestmark = pytest.mark.drake

CENTRE = (0.15, 0.15)


def one_object_world(spec, xy=CENTRE, contact_model="hydroelastic"):
    X = pose(p=(*xy, TABLE_HEIGHT_M + spec.collision_mesh().extents[2] / 2 + 0.001))
    return SimWorld(SceneConfig(objects=((spec, X),)),
                    WorldSettings(contact=SimSettings(contact_model=contact_model)))


def close_fingers(plant, width_m=0.085, target_m=0.0, force_n=40.0, max_s=3.0):
    """Drive the FingerPlant as the emulator does (10 ms ticks) until the fingers stop."""
    for _ in range(int(max_s / 0.01)):
        reading = plant.advance(0.01, width_m, target_m, 0.1, force_n)
        width_m = reading.width_m
        if reading.current_a == 0.0:
            return reading
    raise AssertionError(f"fingers still moving after {max_s} s: {reading}")


@pytest.mark.parametrize("contact_model", ["hydroelastic", "point"])
def test_top_down_grasp_lifts_an_upright_cylinder(contact_model):
    cylinder = procedural_object("cylinder", (0.05, 0.12), mass_kg=0.3)
    world = one_object_world(cylinder, contact_model=contact_model)
    (before,) = world.object_states()
    assert before.height_above_table_m == pytest.approx(0.0, abs=2e-3) and not before.in_hand

    # pre-grasp 0.1 m above the grasp, then straight down: TCP 3 cm below the top
    top_z = TABLE_HEIGHT_M + 0.12
    grasp = pose(R_TOP_DOWN, (*CENTRE, top_z - 0.03))
    above = pose(R_TOP_DOWN, (*CENTRE, top_z + 0.07))
    for target in (above, grasp):
        ok, message = world.move_tcp(target, 0.25)
        assert ok, message
    np.testing.assert_allclose(world.tcp_pose(), grasp, atol=1e-6)

    reading = close_fingers(SimFingerPlant(world))
    assert reading.blocked, reading
    assert reading.width_m == pytest.approx(0.05, abs=0.004)  # the cylinder's diameter

    ok, message = world.move_tcp(above, 0.1)
    assert ok, message
    (after,) = world.object_states()
    rise = after.X_task_object[2, 3] - before.X_task_object[2, 3]
    assert rise > 0.09, f"object rose {rise:.3f} m of the 0.10 m lift"
    assert after.in_hand and after.lifted
    # what a wrist sensor reads: the object's weight, pulling down
    assert world.hand_contact_force_n()[2] == pytest.approx(-0.3 * 9.81, rel=0.1)


def test_fingers_close_fully_on_nothing_and_an_obstacle_stops_the_arm():
    box = procedural_object("box", (0.04, 0.04, 0.08), mass_kg=0.3)
    world = one_object_world(box, xy=(0.03, 0.03))  # well away from the hand's path
    # Closing on nothing, the pads meet short of the closed limit: the gripper reports
    # that stop as an object at its motor position (as a real 2F-85 can), and the
    # executor's empty-closed calibration is what tells it from a held object.
    reading = close_fingers(SimFingerPlant(world))
    assert reading.blocked and reading.width_m < 0.002, reading
    assert world.finger_width_m() < 0.002  # pads meet

    # a finger position target short of closed: reached, not blocked
    reading = close_fingers(SimFingerPlant(world), width_m=0.0, target_m=0.04)
    assert not reading.blocked and reading.width_m == 0.04
    assert world.finger_width_m() == pytest.approx(0.04, abs=0.0015)

    # straight-line motion with a turn: yaw 90 deg and tilted 30 deg, then back
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("zx", [90, 30], degrees=True).as_matrix() @ R_TOP_DOWN
    turned = pose(R, (0.2, 0.1, 0.3))
    start = world.tcp_pose()[:3, 3]
    motion = world.start_move(turned, 0.25)
    world.advance(motion.duration_s / 2)
    mid = world.tcp_pose()[:3, 3]
    line = (turned[:3, 3] - start) / np.linalg.norm(turned[:3, 3] - start)
    off_line = np.linalg.norm((mid - start) - ((mid - start) @ line) * line)
    assert off_line < 1e-4 and 0.3 < (mid - start) @ line / np.linalg.norm(turned[:3, 3] - start) < 0.7
    ok, message = world.move_tcp(turned, 0.25)  # refused: one motion at a time
    assert not ok and "another motion" in message
    while not motion.done.is_set():
        world.advance(0.05)
    assert motion.result[0], motion.result
    np.testing.assert_allclose(world.tcp_pose(), turned, atol=1e-6)

    # the stand-in cannot push the palm through the box (and the box through the table)
    close_fingers(SimFingerPlant(world), width_m=0.04, target_m=0.085)
    box_top = TABLE_HEIGHT_M + 0.08
    above = world.travel(pose(R_TOP_DOWN, (0.03, 0.03, box_top + 0.08)), 0.25)
    assert above.result[0] and above.left_m == 0.0 and not above.stopped_by_contact, above.result
    pressed = world.travel(pose(R_TOP_DOWN, (0.03, 0.03, TABLE_HEIGHT_M + 0.01)), 0.05)
    ok, message = pressed.result
    assert not ok and "stopped by contact" in message and pressed.stopped_by_contact, message
    z = world.tcp_pose()[2, 3]
    assert box_top - 0.06 < z < box_top - 0.05, z  # palm (55 mm behind the TCP) on the box
    assert pressed.left_m == pytest.approx(z - (TABLE_HEIGHT_M + 0.01), abs=1e-6)  # how far short, for the guard
    # The limit counts the force gained since a motion began (a wrist sensor zeroed per
    # motion, as ur_arm reads the UR's): with the limit below the press the hand still
    # exerts, backing off works, and pressing further is stopped at once.
    pressing_n = float(np.linalg.norm(world.hand_contact_force_n()))
    assert pressing_n > 10.0, pressing_n
    world.settings.max_contact_force_n = pressing_n / 2
    ok, message = world.move_tcp(pose(R_TOP_DOWN, (0.03, 0.03, z - 0.005)), 0.05)
    assert not ok and "stopped by contact after 0.00" in message, message
    ok, message = world.move_tcp(pose(R_TOP_DOWN, (0.03, 0.03, box_top + 0.08)), 0.05)
    assert ok, f"{message} (pressing with {pressing_n:.0f} N at the start)"

    reachable, why = world.check_reachable(pose(R_TOP_DOWN, (1.5, 0.15, 0.3)))
    assert not reachable and "outside" in why
    reachable, why = world.check_reachable(pose(R_TOP_DOWN, (*CENTRE, TABLE_HEIGHT_M - 0.01)))
    assert not reachable and "below the table" in why
    (state,) = world.object_states()
    assert not state.in_hand and not state.lifted


@pytest.mark.parametrize("force_n", [100.0, 235.0])
def test_closing_on_nothing_stops_at_any_grip_force(force_n):
    # Above ~46 N the pads meet where the servo's torque (KP x the angle left to the
    # closed target) is under 90 % of its limit; the stop must come from the reference
    # having reached the target, or the gripper reports "moving" for ever (it did: the
    # benchmark's "gripper closing did not finish" timeouts).
    box = procedural_object("box", (0.04, 0.04, 0.08), mass_kg=0.3)
    world = one_object_world(box, xy=(0.03, 0.03))
    world.command_fingers(0.0, 0.1, force_n)
    t_end = world.time_s + 3.0
    while world.finger_status()[1] == "moving" and world.time_s < t_end:
        world.advance(0.01)
    width_m, state = world.finger_status()
    assert state == "blocked" and width_m < 0.002, (width_m, state, world.time_s)
    assert world.time_s < t_end - 1.0  # ~1.2 s for the full stroke at 0.1 m/s


def test_emulator_on_the_sim_clock_reports_contact_on_an_object():
    """GripperEmulator registers -> SimFingerPlant -> physics, clocked by the simulation."""
    box = procedural_object("box", (0.04, 0.03, 0.06), mass_kg=0.2)
    world = one_object_world(box)
    ok, message = world.move_tcp(pose(R_TOP_DOWN, (*CENTRE, TABLE_HEIGHT_M + 0.045)), 0.25)
    assert ok, message
    clock = [0.0]
    emulator = GripperEmulator(plant=SimFingerPlant(world, advances_time=True), activation_time_s=0.0,
                               initial_width_m=world.finger_width_m(), clock=lambda: clock[0])
    emulator.write_registers(COMMAND_ADDRESS, GripperCommand(activate=True).to_registers())
    emulator.advance()
    emulator.write_registers(COMMAND_ADDRESS, GripperCommand(
        activate=True, go=True, position=255, speed=255, force=50).to_registers())
    for _ in range(150):
        clock[0] += 0.01
        emulator.advance()
        if emulator.state.object_status != ObjectStatus.MOVING:
            break
    assert emulator.state.object_status == ObjectStatus.CONTACT_CLOSING
    assert emulator.width_m == pytest.approx(0.03, abs=0.004)
    assert world.object_states()[0].in_hand


def test_depth_image_sees_the_object_and_masses_can_change():
    cylinder = procedural_object("cylinder", (0.06, 0.1), mass_kg=0.4)
    world = one_object_world(cylinder)
    depth, k, T = world.render_depth()
    assert depth.dtype == np.float32 and depth.shape == (k.height, k.width)
    top = np.array([*CENTRE, TABLE_HEIGHT_M + 0.101, 1.0])
    p_cam = np.linalg.inv(T) @ top
    u, v = k.fx * p_cam[0] / p_cam[2] + k.cx, k.fy * p_cam[1] / p_cam[2] + k.cy
    assert depth[int(round(v)), int(round(u))] == pytest.approx(p_cam[2], abs=0.005)
    assert (depth > 0).all()  # the 1 m table fills the view

    name = world.object_names()[0]
    world.set_object_mass(name, 1.5)
    assert world.object_states()[0].mass_kg == pytest.approx(1.5)
    with pytest.raises(ValueError):
        world.set_object_mass(name, -1.0)
    world.remove_object(name)
    world.advance(0.2)  # steps on after a removal (parking it as a locked body crashed SAP)
    assert world.object_states() == []
    with pytest.raises(KeyError):
        world.set_object_mass(name, 1.0)
    depth_after, _, _ = world.render_depth()
    assert depth_after[int(round(v)), int(round(u))] > p_cam[2] + 0.09  # now the table


def test_procedural_scene_is_drawn_settled_and_reloadable():
    world = SimWorld(SceneConfig(seed=3, n_objects=2, arrangement="packed"), WorldSettings())
    names = world.object_names()
    assert 1 <= len(names) <= 2
    for state in world.object_states():
        assert abs(state.height_above_table_m) < 0.003, state  # resting on the table
        assert not state.out_of_workspace and not state.in_hand

    again = world.reset(SceneConfig(seed=3, n_objects=2, arrangement="packed", object_mass_kg=0.7))
    assert again == names  # same seed, same objects
    assert [s.mass_kg for s in world.object_states()] == pytest.approx([0.7] * len(names))
    with pytest.raises(ValueError, match="arrangement"):
        world.reset(SceneConfig(arrangement="heap"))
    assert world.object_names() == names  # a bad request leaves the scene alone


def test_mesh_directory_scene(tmp_path):
    """Bare OBJ files (no mass in them) get object_mass_kg; URDFs would bring their own."""
    import trimesh

    trimesh.creation.box((0.05, 0.06, 0.08)).export(tmp_path / "block.obj")
    trimesh.creation.cylinder(radius=0.03, height=0.1).export(tmp_path / "can.obj")
    world = SimWorld(SceneConfig(seed=0, n_objects=2, mesh_dir=str(tmp_path), object_mass_kg=0.4), WorldSettings())
    assert sorted(world.object_names()) == ["block", "can"]
    for state in world.object_states():
        assert state.mass_kg == pytest.approx(0.4) and abs(state.height_above_table_m) < 0.003
    with pytest.raises(ValueError, match="no .urdf or .obj"):
        world.reset(SceneConfig(mesh_dir=str(tmp_path / "nowhere")))
