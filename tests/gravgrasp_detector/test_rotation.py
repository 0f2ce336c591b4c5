"""Rotation reconstruction (paper Eq. 2 and the compared representations)."""
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from gravgrasp_detector.perception import rotation


def assert_rotations(R):
    eye = torch.eye(3, dtype=R.dtype).expand_as(R)
    torch.testing.assert_close(R.transpose(-1, -2) @ R, eye, atol=1e-5, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(R.shape[:-2], dtype=R.dtype), atol=1e-5, rtol=0)
    # Right-handed column by column: e_x x e_y = e_z.
    torch.testing.assert_close(torch.linalg.cross(R[..., 0], R[..., 1], dim=-1), R[..., 2], atol=1e-5, rtol=0)


@pytest.mark.parametrize("representation", list(rotation.CHANNELS))
def test_random_channels_give_right_handed_rotations(representation):
    g = torch.Generator().manual_seed(1)
    channels = torch.randn(10000, rotation.CHANNELS[representation], generator=g) * torch.rand(10000, 1, generator=g) * 5
    assert_rotations(rotation.reconstruct(representation, channels))


def test_eq2_keeps_ex_direction_and_ez_in_plane():
    g = torch.Generator().manual_seed(2)
    ex, ez = torch.randn(500, 3, generator=g), torch.randn(500, 3, generator=g)
    R = rotation.from_ex_ez(ex, ez)
    torch.testing.assert_close(R[..., 0], ex / ex.norm(dim=-1, keepdim=True), atol=1e-6, rtol=0)
    # e_z lies in span(e~x, e~z), on e~z's side: Gram-Schmidt, not an arbitrary perpendicular.
    normal = torch.linalg.cross(ex, ez, dim=-1)
    assert (R[..., 2] * normal).sum(-1).abs().max() < 1e-4
    assert ((R[..., 2] * ez).sum(-1) > 0).all()
    # e_y = e_z x e_x as in the paper.
    torch.testing.assert_close(R[..., 1], torch.linalg.cross(R[..., 2], R[..., 0], dim=-1), atol=1e-6, rtol=0)


def test_ey_ez_keeps_ey_direction():
    g = torch.Generator().manual_seed(3)
    ey, ez = torch.randn(500, 3, generator=g), torch.randn(500, 3, generator=g)
    R = rotation.from_ey_ez(ey, ez)
    torch.testing.assert_close(R[..., 1], ey / ey.norm(dim=-1, keepdim=True), atol=1e-6, rtol=0)
    assert_rotations(R)


def test_degenerate_parallel_inputs_still_give_rotations():
    v = torch.tensor([[0.0, 0.0, 2.0], [1.0, 1.0, 0.0], [1e-12, 0.0, 0.0]])
    assert_rotations(rotation.from_ex_ez(v, 3 * v))
    assert_rotations(rotation.from_ey_ez(v, -v))


@pytest.mark.parametrize("representation", list(rotation.CHANNELS))
def test_encode_then_reconstruct_is_identity(representation):
    R = torch.tensor(Rotation.random(1000, random_state=4).as_matrix())
    torch.testing.assert_close(rotation.reconstruct(representation, rotation.encode(representation, R)), R, atol=1e-9, rtol=0)


def test_quaternion_matches_scipy_xyzw():
    q = Rotation.random(200, random_state=5)
    R = rotation.from_quat(torch.tensor(q.as_quat()))
    np.testing.assert_allclose(R.numpy(), q.as_matrix(), atol=1e-12)


def test_symmetric_twin_is_180_degrees_about_approach():
    R = torch.tensor(Rotation.random(50, random_state=6).as_matrix())
    twin = rotation.symmetric_twin(R)
    assert_rotations(twin)
    torch.testing.assert_close(twin, R @ torch.tensor(Rotation.from_euler("z", 180, degrees=True).as_matrix()), atol=1e-12, rtol=0)


def test_unknown_representation_is_rejected():
    with pytest.raises(ValueError, match="unknown rotation representation 'euler'"):
        rotation.reconstruct("euler", torch.zeros(1, 3))
