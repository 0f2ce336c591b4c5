"""The 2F-85 register map and unit conversions."""
import pytest

from robotiq_driver.gripper_registers import (
    ActivationStatus,
    GripperCommand,
    GripperScale,
    GripperState,
    ObjectStatus,
    fault_text,
)


def test_manual_close_command_encodes_to_its_registers():
    close = GripperCommand(activate=True, go=True, position=255, speed=255, force=255)
    assert close.to_registers() == (0x0900, 0x00FF, 0xFFFF)  # manual: 09 00 00 FF FF FF
    assert GripperCommand.from_registers(close.to_registers()) == close
    release = GripperCommand(activate=True, auto_release=True, auto_release_open=True, position=7, speed=1, force=2)
    assert release.to_registers() == (0x3100, 0x0007, 0x0102)
    assert GripperCommand.from_registers(release.to_registers()) == release


def test_manual_status_frames_decode():
    activating = GripperState.from_registers((0x1100, 0, 0))
    assert activating.activated and activating.activation_status == ActivationStatus.ACTIVATING
    assert not activating.ready
    closing = GripperState.from_registers((0x3900, 0x00FF, 0x0E0A))
    assert closing.ready and closing.moving and closing.requested == 255
    assert closing.position == 0x0E and closing.current_a == pytest.approx(0.10)
    contact = GripperState.from_registers((0xB900, 0x00FF, 0xBD00))
    assert contact.object_status == ObjectStatus.CONTACT_CLOSING and contact.object_detected
    assert not contact.moving and contact.position == 0xBD


def test_state_round_trips_including_both_fault_nibbles():
    state = GripperState(True, True, ActivationStatus.ACTIVATED, ObjectStatus.AT_POSITION, 0x0E, 0x9, 12, 200, 37)
    assert state.to_registers() == (0xF900, 0x9E0C, 0xC825)
    assert GripperState.from_registers(state.to_registers()) == state
    assert "overcurrent" in state.fault_text
    assert fault_text(0) == "" and "unknown" in fault_text(0x03)


def test_byte_fields_are_range_checked():
    with pytest.raises(ValueError, match="rPR = 256"):
        GripperCommand(activate=True, position=256).to_registers()


def test_scale_maps_the_stroke_and_rejects_out_of_range_values():
    scale = GripperScale()
    assert scale.width_to_counts(0.085) == 0 and scale.width_to_counts(0.0) == 255
    assert scale.width_to_counts(0.0425) == 128
    assert scale.counts_to_width(255) == 0.0 and scale.counts_to_width(0) == pytest.approx(0.085)
    assert scale.speed_to_counts(0.020) == 0 and scale.speed_to_counts(0.150) == 255
    assert scale.force_to_counts(235) == 255 and scale.counts_to_force(0) == 20
    assert scale.counts_to_speed(scale.speed_to_counts(0.1)) == pytest.approx(0.1, abs=0.13 / 255)
    for call, value, text in (
        (scale.width_to_counts, 0.09, r"position = 0.09 m is outside .*0.0..0.085 m"),
        (scale.width_to_counts, float("nan"), "position = nan"),
        (scale.speed_to_counts, 0.01, "speed = 0.01 m/s"),
        (scale.force_to_counts, 250, "force = 250 N"),
    ):
        with pytest.raises(ValueError, match=text):
            call(value)


def test_calibrated_scale_uses_the_units_counts():
    scale = GripperScale(open_counts=3, closed_counts=230)
    assert scale.width_to_counts(0.085) == 3 and scale.width_to_counts(0.0) == 230
    assert scale.counts_to_width(255) == 0.0 and scale.counts_to_width(0) == pytest.approx(0.085)
    with pytest.raises(ValueError, match="open_counts < closed_counts"):
        GripperScale(open_counts=200, closed_counts=100)
