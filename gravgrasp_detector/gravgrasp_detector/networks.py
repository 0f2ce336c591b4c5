"""The grasp network: VGN's 3D FCN backbone with gravity-rejection heads (paper Sec. V).

Input: (B, 1, R, R, R) TSDF grid in tsdf.py's value convention (R = 40).
Per voxel outputs (the voxel is the TCP position):
- score_n: gravity-rejection score in newtons, >= 0 (softplus x score_scale_n),
- validness_logit: logit of "this voxel holds a valid grasp",
- rotation: rotation.CHANNELS[representation] channels, rebuilt by rotation.py.

Encoder: three stride-2 convs (16/32/64 filters, kernels 5/3/3), 40 -> 20 -> 10 -> 5.
Decoder: convs (64/32/16, kernels 3/3/5) with nearest upsampling 5 -> 10 -> 20 -> 40.
Heads: 5x5x5 convs at full resolution. Score and validness form one dense head; the
rotation head is a separate conv so inference can evaluate it only at the few
voxels that survive selection (`rotation_at`), which is most of the head cost.
"""

import torch
import torch.nn as nn
import torch.nn.functional as F

from . import rotation

ARCHITECTURE = "vgn-fcn3d-v1"


def _conv(cin, cout, kernel, stride=1):
    return nn.Conv3d(cin, cout, kernel, stride=stride, padding=kernel // 2)


class GraspNet(nn.Module):
    def __init__(self, rotation_representation="ex-ez", score_scale_n=1.0, resolution=40):
        super().__init__()
        if rotation_representation not in rotation.CHANNELS:
            raise ValueError(
                f"unknown rotation representation {rotation_representation!r}; "
                f"use one of {list(rotation.CHANNELS)}"
            )
        if resolution % 8:
            raise ValueError(f"resolution must be a multiple of 8, got {resolution}")
        self.rotation_representation = rotation_representation
        self.score_scale_n = float(score_scale_n)
        self.resolution = int(resolution)
        self.enc1 = _conv(1, 16, 5, stride=2)
        self.enc2 = _conv(16, 32, 3, stride=2)
        self.enc3 = _conv(32, 64, 3, stride=2)
        self.dec1 = _conv(64, 64, 3)
        self.dec2 = _conv(64, 32, 3)
        self.dec3 = _conv(32, 16, 5)
        self.head_score_validness = _conv(16, 2, 5)
        self.head_rotation = _conv(16, rotation.CHANNELS[rotation_representation], 5)

    def config(self):
        """Constructor arguments, stored in model files."""
        return {
            "rotation_representation": self.rotation_representation,
            "score_scale_n": self.score_scale_n,
            "resolution": self.resolution,
        }

    def features(self, x):
        """(B, 1, R, R, R) grid -> (B, 16, R, R, R) features shared by all heads."""
        r = self.resolution
        x = F.relu(self.enc1(x))
        x = F.relu(self.enc2(x))
        x = F.relu(self.enc3(x))
        x = F.relu(self.dec1(x))
        x = F.interpolate(x, size=r // 4)
        x = F.relu(self.dec2(x))
        x = F.interpolate(x, size=r // 2)
        x = F.relu(self.dec3(x))
        return F.interpolate(x, size=r)

    def score_and_validness(self, features):
        """-> (score_n, validness_logit), each (B, R, R, R)."""
        out = self.head_score_validness(features)
        score_n = F.softplus(out[:, 0].float()) * self.score_scale_n
        return score_n, out[:, 1].float()

    def rotation_channels(self, features):
        """Dense rotation channels (B, C, R, R, R), for training."""
        return self.head_rotation(features)

    def rotation_at(self, features, index):
        """Rotation channels (N, C) at voxels `index` (N, 3) of batch item 0.

        Same result as rotation_channels(features)[0, :, i, j, k], computed only on
        the N 5x5x5 neighbourhoods that are needed (in float32).
        """
        return _conv_at(self.head_rotation, features, index)

    def score_and_validness_at(self, features, index):
        """(score_n (N,), validness_logit (N,)) at voxels `index`, in float32.

        Lets a bf16 pass be re-scored exactly where it matters (the shortlist), so
        ranking is not decided by bf16's 8-bit mantissa.
        """
        out = _conv_at(self.head_score_validness, features, index)
        return F.softplus(out[:, 0]) * self.score_scale_n, out[:, 1]

    def forward(self, x):
        """Dense outputs for training: dict of score_n, validness_logit, rotation."""
        f = self.features(x)
        score_n, validness_logit = self.score_and_validness(f)
        return {
            "score_n": score_n,
            "validness_logit": validness_logit,
            "rotation": self.rotation_channels(f),
        }


def _conv_at(conv, features, index):
    """`conv` (odd kernel, stride 1, 'same' padding) evaluated at voxels (N, 3) of item 0, float32."""
    w, b = conv.weight.float(), conv.bias.float()
    k = w.shape[-1]
    padded = F.pad(features[0:1].float(), (k // 2,) * 6)
    patches = padded.unfold(2, k, 1).unfold(3, k, 1).unfold(4, k, 1)[0]
    i, j, l = index.unbind(-1)
    return torch.einsum("cnxyz,ocxyz->no", patches[:, i, j, l], w) + b
