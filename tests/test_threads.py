"""priortrack.threads.split_rows: every row once, and the row-wise kernels give the same result
split among threads as in one call."""

import threading

import numpy as np
import torch

from priortrack import load_walkjog
from priortrack.filters.marginal_translation import kalman_update, predict_covariance
from priortrack.observation import default_camera
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors import Diffusion
from priortrack.priors.global_motion import to_world
from priortrack.threads import split_rows, torch_threads
from priortrack.body.fk import joint_positions


def test_split_rows_covers_every_row_once_on_the_workers():
    seen, calls = np.zeros(10_000, dtype=int), []

    def run(rows):
        seen[rows] += 1
        calls.append((rows, threading.current_thread().name))

    with torch_threads(2):
        split_rows(10_000, run, min_rows=2048)
    assert (seen == 1).all() and len(calls) == 2
    assert all(name.startswith("priortrack-blocks") for _, name in calls)          # the pool's workers
    seen[:] = 0
    calls.clear()
    with torch_threads(2):
        split_rows(3000, run, min_rows=2048)                     # too few rows for two: one call, here
    assert (seen[:3000] == 1).all() and calls == [(slice(0, 3000), threading.current_thread().name)]


def test_kernels_split_among_threads_equal_one_call():
    walks = list(load_walkjog().walks("train"))
    prior = Diffusion.fit(walks[:2], local=True)
    g = torch.Generator().manual_seed(0)
    n = 5000
    x = (prior.encode(walks[0])[:1].expand(n, -1) + 0.05 * torch.randn(n, prior.state_dim, generator=g,
                                                                       dtype=torch.float64)).float()
    placement = (0.3 * torch.randn(n, 6, generator=g)).float()
    camera = default_camera(joint_positions(walks[0], "eval15"))
    z, _ = camera.project(torch.as_tensor(joint_positions(walks[0], "eval15")[2]))
    C = predict_covariance(torch.zeros(n, 6, 6), torch.full((3,), 0.003), torch.ones(3))
    sigma = torch.full((3,), 0.0025)
    results = []
    for threads in (1, 2):
        with torch_threads(threads):
            joints = prior.space.joints(x)
            world = to_world(joints, placement)
            results.append((joints, world, *kalman_update(world, C, sigma, torch.ones(3), z.float(), JointLikelihood(camera))))
    for one, split in zip(*results):
        assert torch.equal(one, split)
