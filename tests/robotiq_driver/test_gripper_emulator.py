"""The 2F-85 register-level emulator's state machine, on a hand-driven clock."""
import pytest

from robotiq_driver.emulator.emulated_gripper import (
    ILLEGAL_DATA_ADDRESS,
    DeviceException,
    GripperEmulator,
    KinematicFingers,
)
from robotiq_driver.gripper_registers import (
    COMMAND_ADDRESS,
    STATUS_ADDRESS,
    ActivationStatus,
    GripperCommand,
    GripperState,
    ObjectStatus,
)


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


@pytest.fixture
def clock():
    return Clock()


def make(clock, **plant):
    return GripperEmulator(KinematicFingers(**plant), activation_time_s=1.0, initial_width_m=0.03, clock=clock)


def write(emu, **fields):
    emu.write_registers(COMMAND_ADDRESS, GripperCommand(**fields).to_registers())


def status(emu) -> GripperState:
    return GripperState.from_registers(emu.read_registers(STATUS_ADDRESS, 3))


def activate(emu, clock):
    write(emu)
    write(emu, activate=True)
    clock.t += 1.0
    assert status(emu).ready


def test_activation_takes_its_time_and_opens_the_fingers(clock):
    emu = make(clock)
    assert status(emu).activation_status == ActivationStatus.RESET
    write(emu, activate=True)
    clock.t += 0.1
    mid = status(emu)
    assert mid.activated and mid.activation_status == ActivationStatus.ACTIVATING and not mid.ready
    assert mid.position == round(255 - 0.045 / 0.085 * 255)  # 30 mm + 0.1 s at 150 mm/s
    clock.t += 0.5
    assert not status(emu).ready
    clock.t += 0.4
    done = status(emu)
    assert done.ready and done.position == 0 and done.fault == 0


def test_closing_on_an_object_stops_at_its_width_with_gobj_2(clock):
    emu = make(clock, object_width_m=0.040)
    activate(emu, clock)
    write(emu, activate=True, go=True, position=255, speed=255, force=100)  # 150 mm/s
    clock.t += 0.1  # 15 mm travelled of 45 mm to contact
    moving = status(emu)
    assert moving.moving and moving.requested == 255 and moving.current > 0
    assert moving.position == round(255 - 0.070 / 0.085 * 255)
    clock.t += 0.25
    held = status(emu)
    assert held.object_status == ObjectStatus.CONTACT_CLOSING and held.object_detected
    assert held.position == round(255 - 0.040 / 0.085 * 255) and held.current == 0


def test_a_dropped_object_lets_the_fingers_close_and_reports_gobj_3(clock):
    emu = make(clock, object_width_m=0.040)
    activate(emu, clock)
    write(emu, activate=True, go=True, position=255, speed=255, force=100)
    clock.t += 1.0
    assert status(emu).object_status == ObjectStatus.CONTACT_CLOSING
    emu.plant.object_width_m = None
    clock.t += 0.1
    assert status(emu).object_status == ObjectStatus.MOVING
    clock.t += 0.5
    end = status(emu)
    assert end.object_status == ObjectStatus.AT_POSITION and end.position == 255


def test_opening_against_an_inner_object_gives_gobj_1(clock):
    emu = make(clock, inner_width_m=0.050)
    activate(emu, clock)  # activation opens fully: pretend the ring was put on closed fingers
    write(emu, activate=True, go=True, position=255, speed=255, force=0)
    clock.t += 1.0
    write(emu, activate=True, go=True, position=0, speed=0, force=0)  # 20 mm/s
    clock.t += 1.0
    assert status(emu).moving
    clock.t += 2.0
    stopped = status(emu)
    assert stopped.object_status == ObjectStatus.CONTACT_OPENING
    assert stopped.position == round(255 - 0.050 / 0.085 * 255)


def test_speed_register_sets_the_finger_speed(clock):
    emu = make(clock)
    activate(emu, clock)
    write(emu, activate=True, go=True, position=255, speed=0, force=0)  # 20 mm/s: 4.25 s
    clock.t += 4.2
    assert status(emu).moving
    clock.t += 0.1
    assert status(emu).object_status == ObjectStatus.AT_POSITION


def test_go_without_activation_bit_is_fault_7(clock):
    emu = make(clock)
    write(emu, go=True, position=255)
    s = status(emu)
    assert s.fault == 0x07 and not s.activated and not s.go


def test_go_during_activation_is_delayed_then_executed(clock):
    emu = make(clock)
    write(emu, activate=True)
    clock.t += 0.2
    write(emu, activate=True, go=True, position=255, speed=255)
    assert status(emu).fault == 0x05
    clock.t += 0.8
    s = status(emu)
    assert s.ready and s.fault == 0 and s.go and s.requested == 255
    clock.t += 0.6
    assert status(emu).object_status == ObjectStatus.AT_POSITION


def test_clearing_go_stops_the_fingers_where_they_are(clock):
    emu = make(clock)
    activate(emu, clock)
    write(emu, activate=True, go=True, position=255, speed=255, force=0)
    clock.t += 0.2
    write(emu, activate=True, go=False, position=255, speed=255, force=0)
    here = status(emu).position
    clock.t += 1.0
    s = status(emu)
    assert not s.go and s.position == here and 0 < here < 255


def test_major_fault_stops_motion_until_reset_and_reactivation(clock):
    emu = make(clock)
    activate(emu, clock)
    write(emu, activate=True, go=True, position=255, speed=0, force=0)
    clock.t += 0.5
    emu.inject_fault(0x0E)
    here = status(emu).position
    write(emu, activate=True, go=True, position=0, speed=255, force=0)
    clock.t += 1.0
    s = status(emu)
    assert s.fault == 0x0E and s.position == here and "overcurrent" in s.fault_text
    write(emu)  # reset clears it
    assert status(emu).fault == 0 and not status(emu).activated
    activate(emu, clock)


def test_auto_release_opens_slowly_and_needs_a_reset(clock):
    emu = make(clock, object_width_m=0.040)
    activate(emu, clock)
    write(emu, activate=True, go=True, position=255, speed=255)
    clock.t += 1.0
    write(emu, activate=True, auto_release=True, auto_release_open=True)
    assert status(emu).fault == 0x0B
    clock.t += (0.085 - 0.040) / 0.020 + 0.01
    s = status(emu)
    assert s.fault == 0x0F and s.position == 0 and s.activation_status == ActivationStatus.RESET
    write(emu, activate=True, go=True, position=255)
    assert status(emu).fault == 0x0F  # ignored until reset
    write(emu)
    assert status(emu).fault == 0


def test_unmapped_registers_raise_illegal_address(clock):
    emu = make(clock)
    with pytest.raises(DeviceException) as error:
        emu.read_registers(0, 3)
    assert error.value.code == ILLEGAL_DATA_ADDRESS
    with pytest.raises(DeviceException, match="not writable"):
        emu.write_registers(STATUS_ADDRESS, [0, 0, 0])
    # Partial writes and reads inside the blocks are fine; the output block reads back.
    emu.write_registers(COMMAND_ADDRESS + 1, [0x0042])
    assert emu.read_registers(COMMAND_ADDRESS, 3)[1] == 0x0042
    assert len(emu.read_registers(STATUS_ADDRESS + 2, 1)) == 1
