"""Is an object held by a parallel-jaw hand (the Panda)? Decided from the finger positions
and the ground truth, as the 2F-85's is from its object detection (gOBJ) and the
empty-closed calibration (robotiq_driver.grip_calibration): held = the fingers stopped
short of closed, by more than `EMPTY_MARGIN_M`, and an object touches both fingers.

The Panda's gripper reports only its finger positions. Closing on nothing, the joint
limit stops its fingers at an opening of 0 (measured: 0.0 mm at 40 N, the fingers do
not collide with each other in the model), so the margin only has to cover the limit's
compliance; 2 mm is well below anything the baselines propose (VGN's smallest opening is
1.33 voxels, 10 mm). The ground truth rules out fingers stopped on something that is not
between them (the table, a neighbour pressing on one finger)."""

from __future__ import annotations

from dataclasses import dataclass

EMPTY_MARGIN_M = 0.002


@dataclass(frozen=True)
class GripVerdict:
    held: bool
    reason: str
    width_m: float
    objects: tuple = ()  # the objects touching both fingers


def judge_parallel_grip(width_m: float, object_states, margin_m: float = EMPTY_MARGIN_M) -> GripVerdict:
    """`width_m`: the fingers' opening now; `object_states`: SimWorld.object_states()."""
    between = tuple(s.name for s in object_states if s.in_hand)
    mm = width_m * 1e3
    if width_m <= margin_m:
        return GripVerdict(False, f"fingers closed to {mm:.1f} mm (empty below {margin_m * 1e3:.0f} mm): nothing "
                                  "between them", width_m, between)
    if not between:
        return GripVerdict(False, f"fingers stopped at {mm:.1f} mm, but no object touches both fingers", width_m)
    return GripVerdict(True, f"{', '.join(between)} between the fingers at {mm:.1f} mm", width_m, between)
