"""VGN's detector (published weights, vgn.py) with its grasps executed by the Robotiq
2F-85: beside `vgn` (the same grasps on the Panda hand) it separates what the detector
brings from what the hand brings (sim_bridge/doc/baselines.md).

The frame conversion: the same finger-tip depth. Both TCP frames have the same axes
(z = approach, y = the closing axis, x = y x z), so only the origin moves, along z:
- VGN's TCP (physics.panda_hand) is at the Panda fingers' base; the open finger tips
  are FINGER_DEPTH_M = 0.0502 m beyond it (the URDF and finger mesh; VGN's finger_depth
  says 0.05).
- The project's 2F-85 TCP (robotiq_driver.hand_geometry) is the pinch point between the
  pads; the open finger tips are FINGER_TIP_Z_M = 0.0044 m beyond it.
So T_task_2f85tcp = T_task_vgntcp @ Trans(0, 0, 0.0502 - 0.0044 = +0.0458 m).

Why the tips: VGN's labels place the grasp by how deep the finger tips reach past the
surface point (its sampler puts the TCP finger_depth - depth above the surface, depth in
[-0.1, 1.1] x finger_depth), so the tips are what its detector learned to place. With
the tips matched, the Panda's flat pad (0.019 m long, ending at its tips) lies inside the
2F-85's (0.0375 m, ending at its tips): the 2F-85's pads cover every contact the Panda's
would make, and its palm sits 0.059 m behind the tips where the Panda's sits 0.046 m:
no object the Panda took touches the 2F-85's palm. Matching the TCPs instead would stop
the 2F-85's tips 45.8 mm short of VGN's; matching the pad centres would push them 9.4 mm
deeper, into the table under the low top-down grasps. What stays different is the
hands: the 2F-85's linkage carries its pad tips up to 13.5 mm further along the approach
as it closes, and the executor checks that with the 2F-85's own geometry.

Width: VGN keeps widths of 1.33-9.33 voxels (10-70 mm); the 2F-85 opens to 85 mm (the
Panda to 80 mm) and, as VGN's simulation, both executors open the hand fully whatever the
predicted width: every VGN grasp fits, and the width needs no conversion.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from robotiq_driver.hand_geometry import FINGER_TIP_Z_M

from ...physics.panda_hand import FINGER_DEPTH_M
from . import vgn
from .method import Detector

TIP_DEPTH_SHIFT_M = FINGER_DEPTH_M - FINGER_TIP_Z_M  # +0.0458 m along the approach
T_VGNTCP_2F85TCP = np.eye(4)
T_VGNTCP_2F85TCP[2, 3] = TIP_DEPTH_SHIFT_M
T_VGNTCP_2F85TCP.flags.writeable = False


def to_2f85(grasp: vgn.VGNGrasp) -> vgn.VGNGrasp:
    """The VGN grasp with its pose moved to the 2F-85's TCP: the 2F-85's open finger tips
    where the Panda's were (the module doc); quality, width and voxel unchanged."""
    return dataclasses.replace(grasp, pose=np.asarray(grasp.pose) @ T_VGNTCP_2F85TCP)


def make_detector(path, protocol) -> Detector:
    """VGN (the weights at `path`) as the benchmark's Detector for the 2F-85: vgn's, with
    every grasp converted (to_2f85) and, with clear_hand, checked with the 2F-85's hand."""
    return vgn.make_detector(path, protocol, hand="2f85", to_hand=to_2f85)
