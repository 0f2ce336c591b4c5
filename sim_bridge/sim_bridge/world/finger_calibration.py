"""The 2F-85's reported opening against its driver angle in the simulated cell, as the
real gripper reports its motor position (not the pad gap): free-closing calibration of the
Menagerie model in Drake."""

import numpy as np

from ..physics import hand_model

# Free closing of the Menagerie 2F-85 in Drake (slow torque, no object): driver angle ->
# gap between the pad faces. The pads touch each other at 0.775 rad (gap 1.1 mm).
DRIVER_ANGLE_RAD = np.array([0.0, 0.057, 0.101, 0.158, 0.2, 0.258, 0.312, 0.352, 0.404,
                             0.455, 0.505, 0.555, 0.603, 0.651, 0.709, 0.754, 0.775])
PAD_GAP_M = 1e-3 * np.array([85.4, 80.14, 75.99, 70.37, 66.11, 60.07, 54.28, 49.93, 44.13,
                             38.34, 32.59, 26.89, 21.26, 15.7, 8.88, 3.53, 1.1])
STROKE_M = hand_model.MAX_STROKE_M
# d(gap)/d(angle), mean over the stroke: converts the commanded finger speed (m/s of
# opening, as the 2F-85's rSP) to a driver rate.
GAP_PER_DRIVER_RAD_M = (PAD_GAP_M[0] - PAD_GAP_M[-1]) / DRIVER_ANGLE_RAD[-1]


def width_from_driver_angle(angle_rad: float) -> float:
    """Finger opening [m] the 2F-85 reports at a driver angle (clipped to 0..stroke)."""
    w = float(np.interp(angle_rad, DRIVER_ANGLE_RAD, PAD_GAP_M))
    return min(max(w, 0.0), STROKE_M)


def driver_angle_for_width(width_m: float) -> float:
    """Driver angle [rad] for an opening [m]; 0 m gives the closed limit (0.8 rad), beyond
    where the pads meet, so 'close' squeezes whatever is between them."""
    if width_m <= PAD_GAP_M[-1]:
        return hand_model.DRIVER_CLOSED_RAD
    return float(np.interp(width_m, PAD_GAP_M[::-1], DRIVER_ANGLE_RAD[::-1]))
