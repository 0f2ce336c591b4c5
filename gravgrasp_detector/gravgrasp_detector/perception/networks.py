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


def _conv3d(x, weight, bias, stride=1, padding=0):
    """F.conv3d, but float32 inference on CPU always goes to oneDNN.

    PyTorch sends small-batch float32 3x3x3 convolutions to its reference
    `slow_conv3d` (a heuristic for 2-D convs); here that was 15x slower than oneDNN
    for the same result.
    """
    if (x.device.type == "cpu" and x.dtype == torch.float32 and not torch.is_grad_enabled()
            and not torch.is_autocast_cpu_enabled() and hasattr(torch, "mkldnn_convolution")):
        weight = weight.contiguous(memory_format=_layout(x))
        return torch.mkldnn_convolution(x, weight, bias, (padding,) * 3, (stride,) * 3, (1, 1, 1), 1)
    return F.conv3d(x, weight, bias, stride=stride, padding=padding)


def _layout(x):
    return torch.channels_last_3d if x.is_contiguous(memory_format=torch.channels_last_3d) and not x.is_contiguous() else torch.contiguous_format


def _run(conv, x):
    return _conv3d(x, conv.weight, conv.bias, conv.stride[0], conv.padding[0])


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
        return F.interpolate(self.half_features(x), size=self.resolution)

    def half_features(self, x):
        """The decoder output before its last nearest 2x upsampling: (B, 16, R/2, R/2, R/2)."""
        r = self.resolution
        x = F.relu(_run(self.enc1, x))
        x = F.relu(_run(self.enc2, x))
        x = F.relu(_run(self.enc3, x))
        x = F.relu(_run(self.dec1, x))
        x = F.interpolate(x, size=r // 4)
        x = F.relu(_run(self.dec2, x))
        # dec3 reads a nearest 2x upsampling, so its 5^3 conv equals a 3^3 conv on the
        # coarse grid with 8x the outputs, then a parity shuffle (as the score head
        # below): 4.6x fewer MACs in what was ~60 % of the network's CPU time.
        return F.relu(_polyphase_conv(x, self.dec3, self._polyphase(self.dec3)))

    def score_and_validness_from_half(self, half):
        """score_and_validness(features) computed from half_features, ~4.6x fewer MACs.

        The full-resolution features are a nearest 2x upsampling, so the 5^3 head conv
        on them equals, for each of the 8 output parities, a 3^3 conv on the half grid
        whose taps are sums of the 5^3 taps that read the same coarse voxel. One
        16 -> 2x8 conv then a parity shuffle gives the same numbers.
        """
        conv = self.head_score_validness
        out = _polyphase_conv(half, conv, self._polyphase(conv))
        return F.softplus(out[:, 0].float()) * self.score_scale_n, out[:, 1].float()

    def score_and_validness(self, features):
        """-> (score_n, validness_logit), each (B, R, R, R)."""
        out = self.head_score_validness(features)
        score_n = F.softplus(out[:, 0].float()) * self.score_scale_n
        return score_n, out[:, 1].float()

    def rotation_channels(self, features):
        """Dense rotation channels (B, C, R, R, R), for training."""
        return self.head_rotation(features)

    def rotation_at(self, features, index, half=False):
        """Rotation channels (N, C) at voxels `index` (N, 3) of batch item 0.

        Same result as rotation_channels(features)[0, :, i, j, k], computed only on
        the N 5x5x5 neighbourhoods that are needed (in float32). half=True: `features`
        are half_features (the full ones are their nearest 2x upsampling).
        """
        return _conv_at(self.head_rotation, features, index, half)

    def _polyphase(self, conv):
        """Polyphase weights of a 5^3 `conv` (see _polyphase_weights), cached until its
        weights change; when training, recomputed with autograd back to `conv.weight`."""
        weight = conv.weight
        if torch.is_grad_enabled() and weight.requires_grad:
            return _polyphase_weights(weight)
        key = (weight.data_ptr(), weight._version, weight.dtype)
        caches = self.__dict__.setdefault("_polyphase_caches", {})
        cached = caches.get(id(conv))
        if cached is None or cached[0] != key:
            with torch.no_grad(), torch.autocast("cpu", enabled=False):  # exact float32 sums
                cached = (key, _polyphase_weights(weight.detach().float()))
            caches[id(conv)] = cached
        return cached[1]

    def forward_at(self, x, at):
        """Training outputs: dense score_n and validness_logit (B, R, R, R), and the
        rotation channels (N, C) only at the voxels `at` = (batch, i, j, k) index tensors
        (N,), where the loss reads them. Same numbers as `forward` at a fraction of its
        cost: the dense 5^3 rotation head was half of a training step, and the heads and
        dec3 run on the half grid (polyphase) instead of its nearest upsampling."""
        half = self.half_features(x)
        score_n, validness_logit = self.score_and_validness_from_half(half)
        b = at[0]
        index = torch.stack(at[1:], -1)
        rot = torch.zeros(len(b), self.head_rotation.out_channels, device=x.device)
        for item in torch.unique(b).tolist():
            rows = torch.nonzero(b == item).flatten()
            rot = rot.index_put((rows,), _conv_at(self.head_rotation, half[item:item + 1], index[rows], half=True))
        return {"score_n": score_n, "validness_logit": validness_logit, "rotation_at": rot}

    def forward(self, x):
        """Dense outputs (validation, tests): dict of score_n, validness_logit, rotation."""
        f = self.features(x)
        score_n, validness_logit = self.score_and_validness(f)
        return {
            "score_n": score_n,
            "validness_logit": validness_logit,
            "rotation": self.rotation_channels(f),
        }


def _rows(features, flat):
    """features (C, X, Y, Z) in either memory layout, flat voxel indices (...) -> (..., C)."""
    channels = features.shape[0]
    if features.is_contiguous():
        return features.reshape(channels, -1)[:, flat].movedim(0, -1)
    return features.permute(1, 2, 3, 0).reshape(-1, channels)[flat]


def _polyphase_conv(coarse, conv, weight):
    """`conv` (5^3, stride 1, padding 2) on the nearest 2x upsampling of `coarse` (B, C, n, n, n),
    computed on the coarse grid with its polyphase `weight`: (B, O, 2n, 2n, 2n)."""
    y = _conv3d(coarse, weight.to(coarse.dtype), conv.bias.repeat_interleave(8).to(coarse.dtype), padding=1)
    b, n = y.shape[0], y.shape[2]
    out_channels = conv.weight.shape[0]
    y = y.reshape(b, out_channels, 2, 2, 2, n, n, n).permute(0, 1, 5, 2, 6, 3, 7, 4)
    return y.reshape(b, out_channels, 2 * n, 2 * n, 2 * n)


def _polyphase_weights(weight):
    """(O, C, 5, 5, 5) taps on a 2x nearest-upsampled grid -> (O*8, C, 3, 3, 3) on the
    half grid; output channel o*8 + 4 px + 2 py + pz is output o at parity (px, py, pz)."""
    # Along one axis, fine tap t in -2..2 at parity p reads coarse offset floor((p + t) / 2).
    m = torch.zeros(2, 3, 5, dtype=weight.dtype, device=weight.device)
    for p in range(2):
        for t in range(-2, 3):
            m[p, (p + t) // 2 + 1, t + 2] = 1.0
    w = torch.einsum("pax,qby,rcz,okxyz->opqrkabc", m, m, m, weight)
    return w.reshape(weight.shape[0] * 8, weight.shape[1], 3, 3, 3)


def _conv_at(conv, features, index, half=False):
    """`conv` (odd kernel, stride 1, zero 'same' padding) at voxels (N, 3) of item 0, in float32.

    Gathers the N k^3 neighbourhoods straight from `features` in its memory layout
    (channels-first or channels_last_3d): no padded or converted copy of the volume.
    half=True: `features` are at half resolution and stand for their nearest 2x upsampling.
    """
    w = conv.weight.float()
    out_channels, k = w.shape[0], w.shape[-1]
    scale = 2 if half else 1
    size = torch.tensor(features.shape[2:]) * scale
    offsets = torch.arange(k) - k // 2
    offsets = torch.stack(torch.meshgrid(offsets, offsets, offsets, indexing="ij"), -1).reshape(-1, 3)
    pos = index[:, None, :] + offsets  # (N, k^3, 3)
    inside = ((pos >= 0) & (pos < size)).all(-1)
    pos = torch.div(torch.minimum(pos.clamp_min(0), size - 1), scale, rounding_mode="floor")
    size = size // scale
    flat = (pos[..., 0] * size[1] + pos[..., 1]) * size[2] + pos[..., 2]  # (N, k^3)
    patches = _rows(features[0], flat).float() * inside[..., None]  # (N, k^3, C)
    w = w.permute(0, 2, 3, 4, 1).reshape(out_channels, -1)  # (O, k^3 * C), same order
    return patches.reshape(len(index), -1) @ w.T + conv.bias.float()
