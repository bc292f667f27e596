"""Forward kinematics as one fused GPU kernel (Triton), for float32 and float64 channels on CUDA.

The same recursion as the CPU kernel of :mod:`priortrack.body.fk_kernel`, for every joint j
(parents first):

    L_j = Π_k R_{a_k}(θ_k),   G_j = G_parent · L_j,   p_j = p_parent + G_parent · (o_j + T_j),

R_a(θ) = cos θ I + sin θ [a]ₓ + (1 − cos θ) a aᵀ. One program takes BLOCK rows (particles); it
walks the joints in order, keeping each joint's G_j and p_j (12 numbers a row) in a scratch
buffer laid out (J, 12, n) so that every load and store is coalesced; the wanted joints' p_j are
then gathered by torch. The torch path of :class:`priortrack.body.fk.ForwardKinematics` runs about 50
small kernels a level, each reading and writing every row's 3 × 3 frames: at 10⁶ rows it is
bound by those launches and that traffic, which this kernel does once.

Triton comes with PyTorch's CUDA builds on Linux; where it does not import (PyTorch's CPU builds),
ForwardKinematics on a GPU takes its torch path. tests/test_cuda.py checks this kernel
against the torch path on a GPU.
"""

from __future__ import annotations

import numpy as np
import torch
import triton
import triton.language as tl

#: Rows per program.
BLOCK = 256


@triton.jit
def _shift(theta, offsets, trans_channels, j, a, n, i, live, zero):
    """Row a of o_j + T_j: the offset plus the joint's translation channel along axis a, if any."""
    ch = tl.load(trans_channels + 3 * j + a)
    o = tl.load(offsets + 3 * j + a) + zero
    if ch >= 0:
        o += tl.load(theta + ch * n + i, mask=live, other=0.0)
    return o


@triton.jit
def _frames(theta, parents, offsets, axes, rot_channels, trans_channels, scratch, n, J: tl.constexpr,
            BLOCK: tl.constexpr):
    """theta (C, n) planar channels → scratch (J, 12, n): G_j row-major, then p_j."""
    i = tl.program_id(0).to(tl.int64) * BLOCK + tl.arange(0, BLOCK)
    live = i < n
    zero = tl.zeros([BLOCK], dtype=scratch.dtype.element_ty)
    for j in range(J):
        par = tl.load(parents + j)
        s0 = _shift(theta, offsets, trans_channels, j, 0, n, i, live, zero)    # o_j + T_j
        s1 = _shift(theta, offsets, trans_channels, j, 1, n, i, live, zero)
        s2 = _shift(theta, offsets, trans_channels, j, 2, n, i, live, zero)
        if par < 0:
            g00, g01, g02 = zero + 1.0, zero, zero
            g10, g11, g12 = zero, zero + 1.0, zero
            g20, g21, g22 = zero, zero, zero + 1.0
            p0, p1, p2 = s0, s1, s2
        else:
            up = scratch + par * 12 * n + i
            g00 = tl.load(up, mask=live, other=0.0, volatile=True)
            g01 = tl.load(up + n, mask=live, other=0.0, volatile=True)
            g02 = tl.load(up + 2 * n, mask=live, other=0.0, volatile=True)
            g10 = tl.load(up + 3 * n, mask=live, other=0.0, volatile=True)
            g11 = tl.load(up + 4 * n, mask=live, other=0.0, volatile=True)
            g12 = tl.load(up + 5 * n, mask=live, other=0.0, volatile=True)
            g20 = tl.load(up + 6 * n, mask=live, other=0.0, volatile=True)
            g21 = tl.load(up + 7 * n, mask=live, other=0.0, volatile=True)
            g22 = tl.load(up + 8 * n, mask=live, other=0.0, volatile=True)
            p0 = tl.load(up + 9 * n, mask=live, other=0.0, volatile=True) + g00 * s0 + g01 * s1 + g02 * s2
            p1 = tl.load(up + 10 * n, mask=live, other=0.0, volatile=True) + g10 * s0 + g11 * s1 + g12 * s2
            p2 = tl.load(up + 11 * n, mask=live, other=0.0, volatile=True) + g20 * s0 + g21 * s1 + g22 * s2
        for k in tl.static_range(3):                              # G_j ← G_j R_{a_k}(θ_k)
            ch = tl.load(rot_channels + 3 * j + k)
            if ch >= 0:
                x = tl.load(axes + 9 * j + 3 * k)
                y = tl.load(axes + 9 * j + 3 * k + 1)
                z = tl.load(axes + 9 * j + 3 * k + 2)
                angle = tl.load(theta + ch * n + i, mask=live, other=0.0)
                s, c = tl.sin(angle), tl.cos(angle)
                t = 1.0 - c
                r00, r01, r02 = c + t * x * x, t * x * y - s * z, t * x * z + s * y
                r10, r11, r12 = t * x * y + s * z, c + t * y * y, t * y * z - s * x
                r20, r21, r22 = t * x * z - s * y, t * y * z + s * x, c + t * z * z
                g00, g01, g02 = (g00 * r00 + g01 * r10 + g02 * r20, g00 * r01 + g01 * r11 + g02 * r21,
                                 g00 * r02 + g01 * r12 + g02 * r22)
                g10, g11, g12 = (g10 * r00 + g11 * r10 + g12 * r20, g10 * r01 + g11 * r11 + g12 * r21,
                                 g10 * r02 + g11 * r12 + g12 * r22)
                g20, g21, g22 = (g20 * r00 + g21 * r10 + g22 * r20, g20 * r01 + g21 * r11 + g22 * r21,
                                 g20 * r02 + g21 * r12 + g22 * r22)
        here = scratch + j * 12 * n + i
        tl.store(here, g00, mask=live)
        tl.store(here + n, g01, mask=live)
        tl.store(here + 2 * n, g02, mask=live)
        tl.store(here + 3 * n, g10, mask=live)
        tl.store(here + 4 * n, g11, mask=live)
        tl.store(here + 5 * n, g12, mask=live)
        tl.store(here + 6 * n, g20, mask=live)
        tl.store(here + 7 * n, g21, mask=live)
        tl.store(here + 8 * n, g22, mask=live)
        tl.store(here + 9 * n, p0, mask=live)
        tl.store(here + 10 * n, p1, mask=live)
        tl.store(here + 11 * n, p2, mask=live)


class Skeleton:
    """A skeleton's arrays on the GPU, in the kernel's dtype: parents (J,), offsets (J, 3), axes (J, 3, 3),
    rot_channels and trans_channels (J, 3) (−1: unused), as :class:`priortrack.data.skeleton.Skeleton`."""

    def __init__(self, skeleton, device: torch.device, dtype: torch.dtype):
        def as_t(a, kind):
            return torch.as_tensor(np.ascontiguousarray(a), device=device, dtype=kind)
        self.parents = as_t(skeleton.parents, torch.int64)
        self.offsets = as_t(skeleton.offsets, dtype)
        self.axes = as_t(skeleton.rot_axes, dtype)
        self.rot_channels = as_t(skeleton.rot_channels, torch.int64)
        self.trans_channels = as_t(skeleton.trans_channels, torch.int64)


def positions(channels: torch.Tensor, skeleton: Skeleton, wanted: torch.Tensor) -> torch.Tensor:
    """Positions (n, K, 3) of the joints ``wanted`` (K,) int64 for channels (n, C) on a CUDA device, in the
    channels' dtype (float32 or float64): the kernel's p_j rows of the wanted joints."""
    n, J = channels.shape[0], skeleton.parents.shape[0]
    scratch = torch.empty(J, 12, n, dtype=channels.dtype, device=channels.device)
    if n:
        # num_stages=1: Triton's software pipelining would load a parent's rows for joint j + 1 before
        # joint j's stores (a chain's parent is often the joint just written): stale frames, seen on an H200
        _frames[((n + BLOCK - 1) // BLOCK,)](channels.T.contiguous(), skeleton.parents, skeleton.offsets,
                                             skeleton.axes, skeleton.rot_channels, skeleton.trans_channels,
                                             scratch, n, J, BLOCK=BLOCK, num_stages=1)
    return scratch[:, 9:].index_select(0, wanted).permute(2, 0, 1).contiguous()
