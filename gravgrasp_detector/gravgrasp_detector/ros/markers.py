"""RViz markers for grasps: schematic 2F-85 outlines coloured by rank key (no rclpy).

Outline in the TCP frame (z = approach, y = closing axis), fingers open (85 mm):

        y=-0.0425   y=+0.0425
           |   TCP   |        z = 0 (pinch point), fingertips reach z = +0.01
           |    x    |
           +----+----+        palm at z = -0.05
                |
                |             wrist stem to z = -0.09
"""

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from .interface import pose_msg_from_matrix

HALF_OPENING_M = 0.0425
PALM_Z_M = -0.05
TIP_Z_M = 0.01
STEM_Z_M = -0.09

# Line segments (start, end) of the outline, TCP frame.
OUTLINE = np.array([
    [(-HALF_OPENING_M, PALM_Z_M), (HALF_OPENING_M, PALM_Z_M)],  # palm
    [(-HALF_OPENING_M, PALM_Z_M), (-HALF_OPENING_M, TIP_Z_M)],  # finger
    [(HALF_OPENING_M, PALM_Z_M), (HALF_OPENING_M, TIP_Z_M)],  # finger
    [(0.0, PALM_Z_M), (0.0, STEM_Z_M)],  # stem
])


def rank_colour(key, max_key):
    """Red (weakest) -> yellow -> green (strongest of this set)."""
    f = 0.0 if not max_key > 0 else float(np.clip(key / max_key, 0.0, 1.0))
    return ColorRGBA(r=float(min(1.0, 2 * (1 - f))), g=float(min(1.0, 2 * f)), b=0.0, a=1.0)


def grasp_markers(grasps, header, line_width_m=0.002):
    """MarkerArray: DELETEALL, then one LINE_LIST per grasp (namespace 'grasps', id = rank),
    coloured by what the grasps were ranked by (Grasp.rank_key: the score in N, or the
    validness of a binary model, whose score_n is NaN)."""
    out = MarkerArray()
    out.markers.append(Marker(header=header, action=Marker.DELETEALL))
    top = max((g.rank_key for g in grasps), default=0.0)
    points = [Point(x=0.0, y=float(y), z=float(z)) for segment in OUTLINE for (y, z) in segment]
    for rank, g in enumerate(grasps):
        m = Marker(header=header, ns="grasps", id=rank, type=Marker.LINE_LIST, action=Marker.ADD)
        m.pose = pose_msg_from_matrix(g.pose)
        m.scale.x = line_width_m
        m.color = rank_colour(g.rank_key, top)
        m.points = points
        out.markers.append(m)
    return out
