"""Batched FK against pytorch-kinematics (an independent implementation) and its own invariants."""

import numpy as np
import pytest
import torch

from priortrack import PriortrackError, load_motion
from priortrack.body.chain import KinematicChain, to_urdf
from priortrack.body.fk import ForwardKinematics, forward_kinematics
from priortrack.data.bundled import load_bundled

SUBJECTS = ["cmu:07_01", "cmu:35_01", "cmu:131_04", "cmu:135_06", "cmu:49_18"]


def _poses(motion, n=64, spread=0.5, seed=0):
    """Real frames plus large random perturbations of every angle (radians)."""
    rng = np.random.default_rng(seed)
    channels = motion.channels[rng.integers(0, len(motion), n)].copy()
    channels[:, 3:] += rng.normal(0, spread, (n, motion.skeleton.num_channels - 3))
    return channels


@pytest.mark.parametrize("name", SUBJECTS)
def test_fk_agrees_with_pytorch_kinematics_float64(name):
    motion = load_bundled(name)
    channels = _poses(motion)
    ours = ForwardKinematics(motion.skeleton)(channels)
    theirs = KinematicChain(motion.skeleton).positions(channels)
    assert ours.shape == (64, motion.skeleton.num_joints, 3) and ours.dtype == torch.float64
    assert (ours - theirs).abs().max().item() < 1e-9


@pytest.mark.parametrize("name", SUBJECTS)
def test_float32_positions_by_the_fused_kernel_match_float64(name):
    """float32 positions on the CPU come from one fused kernel (priortrack.body.fk_kernel); the
    torch path (rotations, other dtypes and devices) is its reference. On real frames with large
    perturbations, and angles up to ±40 rad (the kernel's sine and cosine reduce them by π/2
    steps): within 1e-5 m of the float64 FK, as close as the torch path's own float32 positions
    are (at most twice as far, plus 1e-6 m), for every joint, chosen joints and a single pose."""
    motion = load_bundled(name)
    channels = _poses(motion, n=256)
    channels[:8, 3:] = np.random.default_rng(1).uniform(-40, 40, (8, motion.skeleton.num_channels - 3))
    p64 = ForwardKinematics(motion.skeleton)(channels)
    fk32 = ForwardKinematics(motion.skeleton, dtype=torch.float32)
    fused = fk32(channels)
    torch32, _ = fk32(channels, rotations=True)                             # the torch path
    assert fused.dtype == torch.float32 and fused.shape == p64.shape
    error, error32 = ((p.double() - p64).abs().max().item() for p in (fused, torch32))
    assert error < 1e-5 and error < 2 * error32 + 1e-6, (error, error32)
    assert torch.equal(fk32(channels, joints=[0, 7, 20]), fused[:, [0, 7, 20]])
    assert torch.equal(fk32(channels[3]), fused[3])


def test_the_fk_kernels_sine_and_cosine_are_float32_accurate():
    """The kernel's branch-free sin and cos on [−40, 40] rad against numpy in float64: within
    3e-7 (float32's rounding near 1 is 6e-8; the reduction by π/2 adds about 1e-9 per turn)."""
    from priortrack.body.fk_kernel import _sin_cos

    theta = np.linspace(-40, 40, 40001, dtype=np.float32)
    sin, cos = (np.array(values, dtype=np.float64) for values in zip(*(_sin_cos(t) for t in theta)))
    assert np.abs(sin - np.sin(theta.astype(np.float64))).max() < 3e-7
    assert np.abs(cos - np.cos(theta.astype(np.float64))).max() < 3e-7


def test_global_rotations_are_rotations_and_match_pytorch_kinematics():
    motion = load_bundled("cmu:131_04")
    channels = _poses(motion, n=16)
    _, G = ForwardKinematics(motion.skeleton)(channels, rotations=True)
    eye = torch.eye(3, dtype=torch.float64)
    assert (G @ G.transpose(-1, -2) - eye).abs().max() < 1e-12
    assert (torch.linalg.det(G) - 1).abs().max() < 1e-12
    chain = KinematicChain(motion.skeleton)
    transforms = chain.chain.forward_kinematics_tensor(chain.joint_values(channels))
    theirs = transforms[chain.frame_index, :, :3, :3].transpose(0, 1)
    assert (G - theirs).abs().max() < 1e-12


def test_single_pose_and_batch_agree_and_gradients_flow():
    motion = load_bundled("cmu:07_01")
    fk = ForwardKinematics(motion.skeleton)
    one = fk(motion.channels[5])
    assert one.shape == (motion.skeleton.num_joints, 3)
    torch.testing.assert_close(one, fk(motion.channels[:10])[5], rtol=0, atol=0)
    x = torch.as_tensor(motion.channels[:4], dtype=torch.float64).requires_grad_()
    fk(x).sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


def test_root_translation_moves_everything_rigidly():
    motion = load_bundled("cmu:07_01")
    a = motion.channels[:3].copy()
    b = a.copy()
    b[:, :3] += [0.3, -0.2, 1.5]
    pa, pb = forward_kinematics(motion.skeleton, a), forward_kinematics(motion.skeleton, b)
    torch.testing.assert_close(pb - pa, torch.tensor([0.3, -0.2, 1.5], dtype=torch.float64).expand_as(pa))


def test_urdf_text_builds_the_same_chain():
    import pytorch_kinematics as pk

    motion = load_bundled("cmu:07_01")
    urdf = to_urdf(motion.skeleton)
    assert urdf.count('type="revolute"') == 59 and urdf.count('type="prismatic"') == 3
    chain = pk.build_chain_from_urdf(urdf).to(dtype=torch.float64)
    names = chain.get_joint_parameter_names()
    assert sorted(names) == sorted(motion.skeleton.channel_names)
    channels = _poses(motion, n=8)
    th = torch.as_tensor(channels[:, [motion.skeleton.channel_names.index(n) for n in names]])
    frames = chain.forward_kinematics(th)
    theirs = torch.stack([frames[n].get_matrix()[:, :3, 3] for n in motion.skeleton.names], 1)
    ours = ForwardKinematics(motion.skeleton)(channels)
    # pytorch-kinematics' URDF parser keeps float32 offsets: 1e-6 m, not 1e-9.
    assert (ours - theirs).abs().max() < 1e-6


def test_wrong_shapes_are_clear_errors():
    motion = load_motion("cmu:07_01")
    fk = ForwardKinematics(motion.skeleton)
    with pytest.raises(PriortrackError, match=r"expected \(\.\.\., 62\)"):
        fk(np.zeros((5, 61)))
    with pytest.raises(PriortrackError, match="expected"):
        fk(np.zeros((2, 5, 62)))
    with pytest.raises(PriortrackError, match=r"joints \[3, 38\] outside the skeleton's 38 joints"):
        fk(np.zeros((2, 62)), joints=[3, 38])
    with pytest.raises(PriortrackError, match="outside the skeleton '07''s 38 joints"):
        motion.skeleton.local_rotations(np.zeros((2, 62)), joints=[-1])


def test_chosen_joints_equal_the_full_result():
    """``joints=`` returns exactly the chosen rows of the full positions, global rotations and
    local rotations (the local ones from the first levels of the tree only)."""
    motion = load_motion("cmu:07_01")
    fk = ForwardKinematics(motion.skeleton)
    channels = torch.as_tensor(_poses(motion, n=8))
    chosen = [0, 5, 17, 30]
    positions, G = fk(channels, rotations=True)
    sub_positions, sub_G = fk(channels, rotations=True, joints=chosen)
    assert torch.equal(sub_positions, positions[:, chosen]) and torch.equal(sub_G, G[:, chosen])
    L = torch.as_tensor(motion.skeleton.local_rotations(channels.numpy()))
    torch.testing.assert_close(torch.as_tensor(motion.skeleton.local_rotations(channels.numpy(), joints=chosen)),
                               L[:, chosen], atol=1e-15, rtol=0)
    # The skeleton's local rotations L_j (axis products) compose to FK's global ones: G_j = G_parent L_j.
    parents = torch.as_tensor(motion.skeleton.parents)
    composed = torch.where((parents >= 0)[:, None, None], G[:, parents.clamp(min=0)] @ L, L)
    torch.testing.assert_close(composed, G, atol=1e-12, rtol=0)


def test_pruned_skeleton_places_the_kept_joints_exactly():
    from priortrack.body.layout import eval15_indices

    motion = load_bundled("cmu:131_04")
    keep = eval15_indices(motion.skeleton)
    small, index = motion.skeleton.pruned(keep)
    assert small.num_joints == 24 and small.num_channels == motion.skeleton.num_channels
    channels = _poses(motion, n=32)
    full = ForwardKinematics(motion.skeleton)(channels)[:, keep]
    torch.testing.assert_close(ForwardKinematics(small)(channels)[:, index], full, rtol=0, atol=1e-15)


@pytest.mark.parametrize("name", SUBJECTS)
def test_float64_positions_by_the_fused_kernel_match_the_torch_path(name):
    """float64 positions (the unscented filter's sigma points) come from the fused kernel too, with
    the C library's sine and cosine: within 1e-12 m of the torch path (asked for rotations, it
    computes the positions itself), angles up to ±40 rad included, for chosen joints and one pose."""
    motion = load_bundled(name)
    channels = _poses(motion, n=300)
    channels[:8, 3:] = np.random.default_rng(2).uniform(-40, 40, (8, motion.skeleton.num_channels - 3))
    fk = ForwardKinematics(motion.skeleton)
    fused = fk(channels)
    reference, _ = fk(channels, rotations=True)
    assert fused.dtype == torch.float64 and fused.shape == reference.shape
    assert (fused - reference).abs().max().item() < 1e-12
    assert torch.equal(fk(channels, joints=[0, 7, 20]), fused[:, [0, 7, 20]])
    assert torch.equal(fk(channels[3]), fused[3])


_INTERPRETED = """
import json, sys
import numpy as np, torch
from priortrack.body.fk import ForwardKinematics
from priortrack.body.fk_triton import Skeleton, positions
from priortrack.data.bundled import load_bundled

motion = load_bundled(sys.argv[1])
rng = np.random.default_rng(0)
channels = motion.channels[rng.integers(0, len(motion), 300)].copy()
channels[:, 3:] += rng.normal(0, 0.5, (300, motion.skeleton.num_channels - 3))
errors = {}
for dtype in (torch.float32, torch.float64):
    rows = torch.as_tensor(channels, dtype=dtype)
    reference, _ = ForwardKinematics(motion.skeleton, dtype=dtype)(rows, rotations=True)
    skeleton = Skeleton(motion.skeleton, torch.device("cpu"), dtype)
    J = motion.skeleton.num_joints
    every = positions(rows, skeleton, torch.arange(J))
    chosen = torch.tensor([J - 1, 0, 4])
    errors[str(dtype)] = [(every - reference).abs().max().item(),
                          (positions(rows, skeleton, chosen) - reference[:, chosen]).abs().max().item(),
                          list(positions(rows[:0], skeleton, chosen).shape)]
print(json.dumps(errors))
"""


@pytest.mark.parametrize("name", ["cmu:07_01", "cmu:49_18"])
def test_the_gpu_kernel_in_tritons_interpreter_gives_the_torch_paths_positions(name):
    """priortrack.body.fk_triton's kernel (what a CUDA GPU runs) executed on the CPU by Triton's interpreter
    (TRITON_INTERPRET=1, set before Triton is imported: a fresh process): every joint and a selection in any
    order equal the torch path's positions to the dtype's rounding, and no rows give none. This checks the
    kernel's arithmetic and indexing; tests/test_cuda.py checks the compiled kernel on a GPU."""
    import json
    import os
    import subprocess
    import sys

    pytest.importorskip("triton", reason="Triton (the dev extra's, on Linux) is not installed")
    env = dict(os.environ, TRITON_INTERPRET="1")
    out = subprocess.run([sys.executable, "-c", _INTERPRETED, name], capture_output=True, text=True, env=env,
                         check=True).stdout
    errors = json.loads(out)
    for dtype, tolerance in (("torch.float32", 2e-5), ("torch.float64", 1e-12)):
        every, chosen, empty = errors[dtype]
        assert every < tolerance and chosen < tolerance and empty == [0, 3, 3]
