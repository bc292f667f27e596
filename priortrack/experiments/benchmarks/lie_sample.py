"""Benchmark: conditional next-pose sampling of the Lie-algebra prior, with scikit-learn's
``GaussianMixture.sample`` on a mixture of the same size timed in the same run for reference.

The two do different work: the Lie prior draws x_t ~ p(x_t | x_{t-1}) for given poses (the
responsibilities π_k(x), a Gaussian conditional per row, a parallel transport and an
exponential map); scikit-learn draws unconditional samples of a full-covariance Gaussian
mixture in the same dimension (56 = 28 pose + 28 velocity tangent coordinates). Timings are
medians over interleaved repeats (:func:`priortrack.experiments.benchmarks.timing.interleaved_median_ms`).
"""

from __future__ import annotations

import logging

import numpy as np
import torch

from priortrack.data.bundled import load_bundled, load_walkjog
from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.timing import interleaved_median_ms, load_average
from priortrack.priors.lie import LiePrior
from priortrack.threads import torch_threads

logger = logging.getLogger(__name__)

#: The bundled CMU walks; with the walk/jog set's training walks they make the bench's training set.
CMU_WALKS = ("cmu:07_01", "cmu:07_02", "cmu:07_09", "cmu:07_10", "cmu:07_11", "cmu:35_01")


def walk_prior(seed: int = 0) -> LiePrior:
    """A Lie prior fitted on the bundled walks (CMU 07 and 35, and the walk/jog set's training walks)."""
    motions = [load_bundled(name) for name in CMU_WALKS] + list(load_walkjog().walks("train"))
    return LiePrior.fit(motions, seed=seed)


def _joint_covariances(prior: LiePrior) -> tuple[np.ndarray, np.ndarray]:
    """Each component's mean (K, 4B) and full covariance (K, 4B, 4B) over (a_1 … a_B, b_1 … b_B)."""
    m = prior.mixture
    k, b = m.components, m.bones
    cov = m.covariances.numpy()
    order = np.concatenate([np.arange(b)[:, None] * 4 + [0, 1], np.arange(b)[:, None] * 4 + [2, 3]]).ravel()
    full = np.zeros((k, 4 * b, 4 * b))
    for j in range(b):
        full[:, 4 * j:4 * j + 4, 4 * j:4 * j + 4] = cov[:, j]
    means = np.concatenate([np.zeros((k, 2 * b)), m.velocity_means.numpy().reshape(k, 2 * b)], axis=1)
    return means, full[:, order][:, :, order]


def bench_lie_sample(n: int = 200_000, threads: int = 2, seed: int = 0, repeats: int = 5,
                     prior: LiePrior | None = None) -> dict:
    """Conditional next-pose samples per second of a Lie prior, float32, with ``threads`` torch threads.

    The poses are frames of the walk/jog set's walks (training and test) drawn at random (seeded),
    ``n`` per call; the prior is ``prior`` or :func:`walk_prior`. The reference is scikit-learn's
    ``GaussianMixture.sample(n)`` with the prior's weights and each component's joint mean and
    full covariance set directly, its BLAS limited to ``threads`` threads.

    Returns:
        ``{"samples_per_s", "clusters", "dims", "sklearn_gmm_samples_per_s", "n", "threads",
        "single_thread_samples_per_s", "load_average"}``, dims the dimension of the joint (pose,
        velocity) tangent space (56); single_thread_samples_per_s, the Lie sampler again with one
        thread, and load_average, the machine's 1, 5 and 15 minute load averages when the timing
        ended (:func:`~priortrack.experiments.benchmarks.timing.load_average`), show whether the threads had
        the cores to themselves.
    """
    try:
        from sklearn.mixture import GaussianMixture
        from threadpoolctl import threadpool_limits
    except ImportError:
        raise PriortrackError("bench lie: scikit-learn is needed for the reference timing "
                              "(pip install scikit-learn)") from None
    if n < 1 or threads < 1 or repeats < 1:
        raise PriortrackError(f"bench lie: n, threads and repeats must be positive (got {n}, {threads}, {repeats})")
    prior = walk_prior(seed) if prior is None else prior
    walks = load_walkjog()
    frames = torch.cat([prior.encode(m) for m in walks.walks("train") + walks.walks("test")])
    g = torch.Generator().manual_seed(seed)
    x = frames[torch.randint(len(frames), (n,), generator=g)].to(torch.float32).contiguous()

    means, covariances = _joint_covariances(prior)
    gmm = GaussianMixture(n_components=prior.clusters, covariance_type="full", random_state=seed)
    gmm.weights_ = prior.mixture.weights.numpy()
    gmm.means_ = means
    gmm.covariances_ = covariances                      # all that GaussianMixture.sample reads

    with torch.inference_mode(), threadpool_limits(limits=threads):
        with torch_threads(threads):
            ms = interleaved_median_ms({"sklearn": lambda: gmm.sample(n), "lie": lambda: prior.sample(x, g)},
                                       repeats)
        with torch_threads(1):
            one = interleaved_median_ms({"lie": lambda: prior.sample(x, g)}, repeats)["lie"]
    load = load_average()
    result = {"samples_per_s": n / (ms["lie"] / 1000), "clusters": prior.clusters, "dims": means.shape[1],
              "sklearn_gmm_samples_per_s": n / (ms["sklearn"] / 1000), "n": n, "threads": threads,
              "single_thread_samples_per_s": n / (one / 1000),
              "load_average": None if load is None else [round(value, 2) for value in load]}
    logger.info("bench lie: %.0f samples/s with %d threads (%.0f/s with one), sklearn GaussianMixture.sample "
                "%.0f/s; %d clusters", result["samples_per_s"], threads, result["single_thread_samples_per_s"],
                result["sklearn_gmm_samples_per_s"], prior.clusters)
    if threads > 1 and result["samples_per_s"] < result["single_thread_samples_per_s"]:
        logger.warning("bench lie: %d threads ran slower than one: the cores are busy with other work "
                       "(load average %s), so the timing understates the sampler", threads, result["load_average"])
    return result
