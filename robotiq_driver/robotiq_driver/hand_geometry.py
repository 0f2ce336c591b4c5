"""Geometry of the Robotiq 2F-85 that planning needs: key dimensions and a box model
of the open hand in the TCP frame.

Lives with the gripper driver because every package needs it and all of them depend
on this one: the executor checks the hand against the TSDF with it, data generation
filters scene grasps with it, and the Drake model is measured against it.

TCP frame: origin at the pinch point between the pads, z = approach (palm -> object),
y = finger closing axis, x = y x z. Metres. Values measured on MuJoCo Menagerie's
2F-85 at zero joint angles (fully open); see sim_bridge/README.md.

     y = closing axis ->          z = approach (down the page)
          |  |                |  |      distal links + pads: inner face at
          |  |      TCP       |  |      y = +-stroke/2, up to the finger tips
        /  /         +         \\  \\     proximal links (open: tilted outwards)
      '--------------------------'      palm face, z = -PALM_TO_TCP_M
      |          housing           |    flange at z = -FLANGE_TO_TCP_M
          |     wrist / arm stub   |
"""
import numpy as np

MAX_STROKE_M = 0.085  # distance between the pads when fully open
FLANGE_TO_TCP_M = 0.1558  # flange -> pinch point along the approach axis
FLANGE_TO_PALM_M = 0.1008  # flange -> top of the palm (base housing) on the hand axis
PALM_TO_TCP_M = FLANGE_TO_TCP_M - FLANGE_TO_PALM_M  # 0.055: how deep an object can sit
FINGER_LENGTH_M = 0.0594  # palm top -> fingertip (pad top) when open, along the approach
PAD_LENGTH_M = 0.0375  # along the approach axis
PAD_WIDTH_M = 0.022  # along x
BODY_HALF_EXTENTS_M = (0.0375, 0.0424)  # housing half size along TCP x, y
FINGER_HALF_WIDTH_X_M = 0.0195  # widest finger link (spring link) half width along x

PALM_FACE_Z_M = -PALM_TO_TCP_M                    # deepest possible insertion
FINGER_TIP_Z_M = FINGER_LENGTH_M - PALM_TO_TCP_M  # finger tips beyond the pinch point
WRIST_STUB_M = 0.08          # arm flange / wrist behind the hand, coarse
FINGER_THICKNESS_M = 0.02    # distal link + pad, across the closing axis
PROXIMAL_OUTER_Y_M = 0.078   # open proximal links reach this far out
PROXIMAL_TOP_Z_M = -0.033    # ... and end where the distal link starts


def _mirror_y(box):
    (x0, y0, z0), (x1, y1, z1) = box
    return [[x0, -y1, z0], [x1, -y0, z1]]


_h = MAX_STROKE_M / 2
_bx, _by = BODY_HALF_EXTENTS_M
_distal = [[-PAD_WIDTH_M / 2, _h, PROXIMAL_TOP_Z_M - 0.002],
           [PAD_WIDTH_M / 2, _h + FINGER_THICKNESS_M, FINGER_TIP_Z_M]]
_proximal = [[-FINGER_HALF_WIDTH_X_M, _h + 0.002, PALM_FACE_Z_M],
             [FINGER_HALF_WIDTH_X_M, PROXIMAL_OUTER_Y_M, PROXIMAL_TOP_Z_M]]

HAND_PARTS = ("housing", "wrist", "right proximal link", "left proximal link", "right distal link",
              "left distal link")
# (lo, hi) corners in the TCP frame [m], in the order of HAND_PARTS.
OPEN_HAND_BOXES_TCP = np.array([
    [[-_bx, -_by, -FLANGE_TO_TCP_M], [_bx, _by, PALM_FACE_Z_M]],
    [[-0.045, -0.045, -FLANGE_TO_TCP_M - WRIST_STUB_M], [0.045, 0.045, -FLANGE_TO_TCP_M]],
    _proximal, _mirror_y(_proximal),
    _distal, _mirror_y(_distal),
])


def swept_boxes(approach_m: float) -> np.ndarray:
    """The open-hand boxes extended back along -z by `approach_m`: the volume the hand
    sweeps moving from the pre-grasp pose to the grasp pose."""
    boxes = OPEN_HAND_BOXES_TCP.copy()
    boxes[:, 0, 2] -= approach_m
    return boxes


# Closing moves the pad tips further along the approach: the linkage turns the fingers
# inwards and down. (opening between the pads [m], pad tip z in the TCP frame [m]) of the
# fingers closing on nothing, measured on the Drake model (sim_bridge hand_model
# .FingerKinematics; tests/sim_bridge/test_hand_model.py checks it).
PAD_TIP_Z_BY_OPENING_M = np.array([
    (0.0, 0.0179), (0.0136, 0.0179), (0.0207, 0.0176), (0.0277, 0.0172), (0.0347, 0.0165),
    (0.0416, 0.0157), (0.0484, 0.0146), (0.0550, 0.0134), (0.0615, 0.0120), (0.0678, 0.0103),
    (0.0739, 0.0085), (0.0798, 0.0066), (0.0854, 0.0044)])
PAD_BACK_M = 0.008  # pad thickness behind its gripping face


def pad_tip_z_m(opening_m) -> np.ndarray:
    """Pad tip z in the TCP frame [m] with the fingers closed to `opening_m` (array-like)."""
    return np.interp(opening_m, PAD_TIP_Z_BY_OPENING_M[:, 0], PAD_TIP_Z_BY_OPENING_M[:, 1])


def closed_pad_tips_tcp(opening_m) -> np.ndarray:
    """(N, 8, 3): the tip corners of both pads in the TCP frame [m] with the fingers
    closed (in parallel, as on nothing or a precision grasp) to each `opening_m` (N,):
    where they reach once they stop on an object that wide."""
    w = np.atleast_1d(np.asarray(opening_m, float))
    x = np.array([-1, -1, 1, 1] * 2) * PAD_WIDTH_M / 2
    inner = np.array([0, 1, 0, 1] * 2) * PAD_BACK_M
    side = np.array([-1] * 4 + [1] * 4)
    tips = np.empty((len(w), 8, 3))
    tips[:, :, 0] = x
    tips[:, :, 1] = side * (w[:, None] / 2 + inner)
    tips[:, :, 2] = pad_tip_z_m(w)[:, None]
    return tips


def lowest_z_m(X_task_tcp, points_tcp) -> np.ndarray:
    """(N,) task-frame height [m] of the lowest of the points `points_tcp`, given in the
    TCP frame ((K, 3) for every pose, or (N, K, 3) per pose), at each pose (N, 4, 4)."""
    X = np.asarray(X_task_tcp, dtype=float).reshape(-1, 4, 4)
    P = np.broadcast_to(np.asarray(points_tcp, dtype=float), (len(X),) + np.shape(points_tcp)[-2:])
    return (np.einsum("nj,nkj->nk", X[:, 2, :3], P) + X[:, 2, 3][:, None]).min(axis=1)


def closed_tips_lowest_z(X_task_tcp, opening_m) -> np.ndarray:
    """(N,) task-frame height [m] of the lowest pad tip with the fingers closed to
    `opening_m` (N,) at each pose: closing reaches up to 13.5 mm further along the
    approach than the open hand."""
    return lowest_z_m(X_task_tcp, closed_pad_tips_tcp(opening_m))


def closing_opening_m(X_task_tcp, points_task, fallback_m) -> np.ndarray:
    """(N,) opening [m] at which the pads will stop: the extent, along the closing axis,
    of the points (M, 3) between the pads (inside the stroke, across the pad width, along
    the pads' reach from open to closed). `fallback_m` (N,) where none are."""
    X = np.asarray(X_task_tcp, dtype=float).reshape(-1, 4, 4)
    P = np.asarray(points_task, dtype=float).reshape(-1, 3)
    out = np.array(fallback_m, dtype=float).reshape(-1).copy()
    half_x, half_y = PAD_WIDTH_M / 2, MAX_STROKE_M / 2
    z_lo, z_hi = OPEN_HAND_BOXES_TCP[-1][0][2], pad_tip_z_m(0.0)
    for k in range(len(X)):
        q = (P - X[k, :3, 3]) @ X[k, :3, :3]
        between = (np.abs(q[:, 0]) <= half_x) & (np.abs(q[:, 1]) <= half_y) & (q[:, 2] >= z_lo) & (q[:, 2] <= z_hi)
        if between.any():
            out[k] = np.ptp(q[between, 1])
    return out
