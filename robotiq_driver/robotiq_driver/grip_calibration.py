"""Is something held? gOBJ, judged against where this gripper's fingers close on nothing.

gOBJ = 2 ("stopped on an object while closing") alone does not mean an object: asked
to close fully on nothing, a 2F-85 can stop with its fingertips touching each other and
report an object, at an opening that differs from unit to unit (pads, wear, force).
A fixed "closed" threshold is therefore unsafe: a unit that stops at 3.7 mm passes a
3 mm limit with an empty hand. So, as a user of a real 2F-85 does, measure once per
connection where the fingers stop when they close on nothing (at the grip's speed and
force, which move that point), or take a stored measurement, and call a grip *held*
only when gOBJ is 2 **and** the opening is clearly wider than that point:

    held  <=>  gOBJ == 2  and  opening >= empty_closed_width_m + min_object_width_m

The price: an object thinner than `min_object_width_m` (or a fingertip pinch within
that distance of the empty-closed point) counts as "nothing", never as a false success.
"""
from __future__ import annotations

import dataclasses

from .gripper_client import GripperError
from .gripper_registers import ObjectStatus

# A 2F-85 closing on nothing stops within a few millimetres of zero opening. A
# calibration that stops wider closed on something: refuse it rather than believe it.
MAX_EMPTY_CLOSED_M = 0.010
DEFAULT_MIN_OBJECT_WIDTH_M = 0.002  # ~6 position counts: well above the reading's jitter


class CalibrationError(GripperError):
    """The empty-closed calibration could not be trusted (something between the fingers)."""


@dataclasses.dataclass(frozen=True)
class EmptyClosedCalibration:
    width_m: float        # opening where the fingers stop when closing on nothing
    object_status: int    # gOBJ the gripper reported there (2: fingertips met, 3: at position)
    speed_mps: float      # the speed and force it was measured at
    force_n: float
    source: str           # "measured" (this connection) or "stored" (a parameter)

    def describe(self) -> str:
        how = "measured on connection" if self.source == "measured" else "stored"
        obj = f", gOBJ {self.object_status}" if self.object_status >= 0 else ""
        return f"fingers close on nothing at {self.width_m * 1e3:.1f} mm ({how}{obj})"


@dataclasses.dataclass(frozen=True)
class GripVerdict:
    held: bool
    reason: str


def stored_calibration(width_m: float, speed_mps: float, force_n: float) -> EmptyClosedCalibration:
    if not 0.0 <= width_m <= MAX_EMPTY_CLOSED_M:
        raise ValueError(f"stored empty-closed opening {width_m * 1e3:.1f} mm is outside 0..{MAX_EMPTY_CLOSED_M * 1e3:.0f} mm: "
                         "measure it (gripper_cli calibrate) or leave it unset to calibrate on connection")
    return EmptyClosedCalibration(float(width_m), -1, speed_mps, force_n, "stored")


def calibrate_empty_closed(gripper, speed_mps: float, force_n: float, timeout_s: float) -> EmptyClosedCalibration:
    """Open fully, close on nothing, read where the fingers stopped, open again.

    `gripper` is a robotiq_driver.gripper_client.Robotiq2F85 (or anything with its
    move_and_wait / width_m / scale). The hand must be empty: opening first releases
    whatever it holds. Raises CalibrationError when the fingers stop too wide."""
    stroke = gripper.scale.stroke_m
    gripper.move_and_wait(stroke, speed_mps, force_n, timeout_s=timeout_s)
    closed = gripper.move_and_wait(0.0, speed_mps, force_n, timeout_s=timeout_s)
    width = gripper.width_m(closed)
    gripper.move_and_wait(stroke, speed_mps, force_n, timeout_s=timeout_s)
    if width > MAX_EMPTY_CLOSED_M:
        raise CalibrationError(
            f"calibration: closing on nothing stopped at {width * 1e3:.1f} mm (gOBJ {int(closed.object_status)}), "
            f"more than the {MAX_EMPTY_CLOSED_M * 1e3:.0f} mm a 2F-85 closes to: something is between or "
            "blocks the fingers; clear them and arm again")
    return EmptyClosedCalibration(width, int(closed.object_status), speed_mps, force_n, "measured")


def judge_grip(object_status: int, width_m: float, calibration: EmptyClosedCalibration,
               min_object_width_m: float = DEFAULT_MIN_OBJECT_WIDTH_M) -> GripVerdict:
    """Held or not, with the reason in one phrase (opening and gOBJ included)."""
    limit = calibration.width_m + min_object_width_m
    where = f"opening {width_m * 1e3:.1f} mm, gOBJ {int(object_status)}"
    if object_status != ObjectStatus.CONTACT_CLOSING:
        return GripVerdict(False, f"the fingers did not stop on an object ({where})")
    if width_m < limit:
        return GripVerdict(False, f"the fingers stopped where they close on nothing ({where}; empty-closed "
                                  f"{calibration.width_m * 1e3:.1f} mm + {min_object_width_m * 1e3:.1f} mm "
                                  "needed for an object)")
    return GripVerdict(True, where)
