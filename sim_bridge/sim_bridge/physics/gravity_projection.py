"""Gravity-rejection score: paper Eq. 1.

The grasp simulation measures a 6-dimensional *disturbance-rejection score*
``f_i`` [N]: the largest force, applied at the object's centre of mass along the
TCP-frame direction ``d_i`` (order +x, -x, +y, -y, +z, -z), that the grasp holds.
In a scene the gravity direction ``n_g`` is known, so the score is projected to

    f_g = min_{i : n_i . n_g > eps}  f_i / (n_i . n_g),      n_i = R_scene_tcp d_i.

Reading: a pull of size F along n_g has the component F (n_i . n_g) along n_i;
the grasp holds it while that component is below f_i for every direction that
the pull loads, hence the min.  At least one of the six axis directions always
has n_i . n_g >= 1/sqrt(3), so the admissible set is never empty for eps < 0.577.

eps (GRAVITY_PROJECTION_EPS = 0.05, about 87 degrees from gravity): directions
almost perpendicular to gravity would be divided by a near-zero cosine; they carry
almost none of the load, and the 6-axis sampling of the score says little about
them, so we ignore them instead of letting a 20x (or larger) amplification of a
small f_i decide the min.
"""

import numpy as np

GRAVITY_PROJECTION_EPS = 0.05

# Disturbance directions in the TCP frame, in the order of GraspOutcome.scores_n.
DISTURBANCE_DIRECTIONS_TCP = np.array(
    [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0],
     [0.0, 1.0, 0.0], [0.0, -1.0, 0.0],
     [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])

# Gravity in the task frame (z up).
GRAVITY_DIRECTION_TASK = np.array([0.0, 0.0, -1.0])


def gravity_rejection_score(scores_n, R_scene_tcp, n_g=GRAVITY_DIRECTION_TASK,
                            eps=GRAVITY_PROJECTION_EPS):
    """f_g [N] of one grasp or a batch.

    scores_n: (6,) or (N, 6) disturbance-rejection scores [N], TCP-frame order
        +x, -x, +y, -y, +z, -z.
    R_scene_tcp: (3, 3) or (N, 3, 3) rotation of the TCP frame in the scene frame.
    n_g: gravity direction in the scene frame (normalized here).
    Returns a float for one grasp, else an (N,) array.
    """
    scores = np.asarray(scores_n, dtype=float)
    R = np.asarray(R_scene_tcp, dtype=float)
    single = scores.ndim == 1
    scores = np.atleast_2d(scores)
    if R.ndim == 2:
        R = R[None]
    if scores.shape[1] != 6 or R.shape[1:] != (3, 3) or len(R) != len(scores):
        raise ValueError(f"shapes do not match: scores {scores.shape}, R {R.shape}")
    g = np.asarray(n_g, dtype=float)
    g = g / np.linalg.norm(g)
    # n_i . n_g = (R d_i) . g = d_i . (R^T g); the d_i are +-axes, so the six
    # cosines are +-(R^T g).
    g_tcp = np.einsum("nji,j->ni", R, g)
    cosines = np.concatenate([g_tcp[:, :, None], -g_tcp[:, :, None]], axis=2).reshape(-1, 6)
    loaded = cosines > eps
    ratios = np.where(loaded, scores / np.where(loaded, cosines, 1.0), np.inf)
    f_g = ratios.min(axis=1)
    return float(f_g[0]) if single else f_g
