"""Rotation representations the network regresses, and their reconstruction to R.

R = [e_x, e_y, e_z] (columns) is the TCP orientation in the task frame: e_z is the
approach direction (palm -> object), e_y the finger closing axis, e_x = e_y x e_z.

- "ex-ez" (paper Eq. 2, the default): 6 channels (e~x, e~z). e_x = e~x/|e~x|;
  e_z = Gram-Schmidt of e~z against e_x; e_y = e_z x e_x.
- "ey-ez" (the paper's opposite order): 6 channels (e~y, e~z). e_y = e~y/|e~y|;
  e_z = Gram-Schmidt of e~z against e_y; e_x = e_y x e_z.
- "quat": 4 channels (x, y, z, w) like scipy and VGN, normalised.

All functions take torch tensors with the channels in the last dimension and return
(..., 3, 3), so the training loss and detection use the same code.
"""

import torch

CHANNELS = {"ex-ez": 6, "ey-ez": 6, "quat": 4}

_EPS = 1e-8


def _normalize(v):
    return v / v.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def _orthogonalize(primary, secondary):
    """Unit `primary`, and `secondary` made unit and orthogonal to it (Eq. 2).

    Degenerate inputs still give a rotation: a zero `primary` becomes the task x
    axis, and a `secondary` (nearly) parallel to it any orthogonal unit vector.
    """
    norm_a = primary.norm(dim=-1, keepdim=True)
    x_axis = torch.zeros_like(primary)
    x_axis[..., 0] = 1.0
    a = torch.where(norm_a > 1e-9, primary / norm_a.clamp_min(_EPS), x_axis)
    b = secondary - (a * secondary).sum(-1, keepdim=True) * a
    norm = b.norm(dim=-1, keepdim=True)
    # Fallback: cross with the world axis least aligned with a.
    axis = torch.zeros_like(a)
    axis.scatter_(-1, a.abs().argmin(dim=-1, keepdim=True), 1.0)
    fallback = _normalize(torch.linalg.cross(a, axis, dim=-1))
    b = torch.where(norm > 1e-6, b / norm.clamp_min(_EPS), fallback)
    return a, b


def from_ex_ez(ex, ez):
    e_x, e_z = _orthogonalize(ex, ez)
    e_y = torch.linalg.cross(e_z, e_x, dim=-1)
    return torch.stack((e_x, e_y, e_z), dim=-1)


def from_ey_ez(ey, ez):
    e_y, e_z = _orthogonalize(ey, ez)
    e_x = torch.linalg.cross(e_y, e_z, dim=-1)
    return torch.stack((e_x, e_y, e_z), dim=-1)


def from_quat(q):
    """Unit quaternion (x, y, z, w) -> R; q need not be normalised."""
    x, y, z, w = _normalize(q).unbind(-1)
    return torch.stack(
        (
            torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)), -1),
            torch.stack((2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)), -1),
            torch.stack((2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)), -1),
        ),
        dim=-2,
    )


def reconstruct(representation, channels):
    """(..., C) network rotation channels -> (..., 3, 3) right-handed rotation."""
    if representation == "ex-ez":
        return from_ex_ez(channels[..., 0:3], channels[..., 3:6])
    if representation == "ey-ez":
        return from_ey_ez(channels[..., 0:3], channels[..., 3:6])
    if representation == "quat":
        return from_quat(channels[..., 0:4])
    raise ValueError(f"unknown rotation representation {representation!r}; use one of {list(CHANNELS)}")


def encode(representation, R):
    """(..., 3, 3) rotation -> the (..., C) training target of `representation`."""
    if representation == "ex-ez":
        return torch.cat((R[..., :, 0], R[..., :, 2]), dim=-1)
    if representation == "ey-ez":
        return torch.cat((R[..., :, 1], R[..., :, 2]), dim=-1)
    if representation == "quat":
        return _quat_from_matrix(R)
    raise ValueError(f"unknown rotation representation {representation!r}; use one of {list(CHANNELS)}")


def symmetric_twin(R):
    """The same 2F-85 grasp turned 180 deg about its approach axis z: (x, y) -> (-x, -y)."""
    return R * torch.tensor([-1.0, -1.0, 1.0], dtype=R.dtype, device=R.device)


def _quat_from_matrix(R):
    # Shepperd's method, branch-free: pick the largest of 4 candidate denominators.
    m = R
    t = torch.stack(
        (
            1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
            1 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2],
        ),
        dim=-1,
    )
    candidates = torch.stack(
        (
            torch.stack((t[..., 0], m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] - m[..., 1, 2]), -1),
            torch.stack((m[..., 1, 0] + m[..., 0, 1], t[..., 1], m[..., 2, 1] + m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0]), -1),
            torch.stack((m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2], t[..., 2], m[..., 1, 0] - m[..., 0, 1]), -1),
            torch.stack((m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1], t[..., 3]), -1),
        ),
        dim=-2,
    )
    best = t.argmax(dim=-1)
    q = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = _normalize(q)
    return torch.where(q[..., 3:4] < 0, -q, q)  # w >= 0
