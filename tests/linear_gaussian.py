"""A linear-Gaussian state-space model with the filter interface, and the Kalman filter as its
exact reference (shared by the particle and unscented filter tests)."""

import contextlib

import numpy as np
import torch
from scipy.stats import multivariate_normal


class LinearGaussian:
    """s_t = A s_{t-1} + N(0, Q), z_t = H s_t + N(0, R): the filter interface, linear.

    Also keeps the unscented filter's interface (Euclidean: tangent coordinates are the state's
    own, ⊞ = +, ⊟ = −, no change of coordinates between base points).
    """

    def __init__(self, A, Q, H, R):
        self.A, self.Q, self.H, self.R = (torch.as_tensor(m, dtype=torch.float64) for m in (A, Q, H, R))
        self.dim, self.observation_shape = self.A.shape[0], (self.H.shape[0],)
        self.measurement_block = 1
        self.tangent_dim = self.dim
        self.LQ = torch.linalg.cholesky(self.Q)

    def predict(self, s, generator):
        noise = torch.randn(s.shape, generator=generator, dtype=s.dtype) @ self.LQ.T
        return s @ self.A.T + noise

    def log_transition(self, s_next, s):
        """(B,) log N(s_next; A s, Q) of rows s_next, s (B, n)."""
        return torch.distributions.MultivariateNormal(s @ self.A.T, self.Q).log_prob(s_next)

    def mean_step(self, s):
        return s @ self.A.T

    def observe(self, s):
        return s @ self.H.T

    def log_likelihood(self, predicted, z):
        seen = torch.isfinite(z)
        d = (z - predicted)[:, seen]
        R = self.R[seen][:, seen]
        return torch.distributions.MultivariateNormal(torch.zeros(len(R), dtype=d.dtype), R).log_prob(d)

    # the particle filter's resample-move
    def pose_step(self, s, parents):
        return (s - parents).pow(2).mean(0).sqrt()

    def perturb(self, s, std, generator):
        return s + torch.randn(s.shape, generator=generator, dtype=s.dtype) * std

    def gate(self, z):
        """No validation gate: every observation is kept."""
        return torch.as_tensor(z, dtype=torch.float64), 0

    def mean(self, s, weights):
        return (weights[:, None] * s).sum(0) / weights.sum()

    # the unscented filter's interface
    def measure(self, s):
        return self.observe(s)

    def measurement(self, z):
        return torch.as_tensor(z, dtype=torch.float64).reshape(-1), self.R

    def process_covariance(self, s):
        return self.Q

    def boxplus(self, s, v):
        return s + v

    def boxminus(self, s, base):
        return s - base

    def sigma_mean(self, s, w):
        return w @ s

    def transport(self, a, b):
        return torch.eye(self.dim, dtype=torch.float64)


def kalman_step(model, m, P, z, b=0.0, Q=None):
    """One Kalman step of s_t = A s + b + N(0, Q) (Q the model's unless given), z = H s + N(0, R), NaN = missing:
    the mean, the covariance and ln N(z; ẑ, S) of the coordinates seen (0 where none is)."""
    A, H, R = (t.numpy() for t in (model.A, model.H, model.R))
    Q = model.Q.numpy() if Q is None else Q
    m, P = A @ m + b, A @ P @ A.T + Q
    seen = np.isfinite(z)
    if not seen.any():
        return m, P, 0.0
    Hs, Rs = H[seen], R[np.ix_(seen, seen)]
    S = Hs @ P @ Hs.T + Rs
    K = np.linalg.solve(S, Hs @ P).T
    return m + K @ (z[seen] - Hs @ m), P - K @ S @ K.T, multivariate_normal(Hs @ m, S).logpdf(z[seen])


def kalman(model, m0, P0, zs):
    """The Kalman filter's (mean, covariance) after the observations zs (T, m), NaN = missing."""
    m, P = m0.copy(), P0.copy()
    for z in zs:
        m, P, _ = kalman_step(model, m, P, z)
    return m, P


@contextlib.contextmanager
def thread_counts(model, method: str):
    """Inside the block torch runs on 2 threads and ``model.method`` records torch's thread count at each call into
    the list the block gets; both are given back after."""
    seen, original, previous = [], getattr(model, method), torch.get_num_threads()
    setattr(model, method, lambda *args: (seen.append(torch.get_num_threads()), original(*args))[1])
    torch.set_num_threads(2)
    try:
        yield seen
    finally:
        setattr(model, method, original)
        torch.set_num_threads(previous)


def kalman_rts(model, m0, P0, zs):
    """The Rauch–Tung–Striebel smoother's (means (T, n), covariances (T, n, n)) of the states after
    each observation in zs (T, m), NaN = missing, from the Kalman filter's posteriors."""
    A, Q = model.A.numpy(), model.Q.numpy()
    filtered = [kalman(model, m0, P0, zs[:t + 1]) for t in range(len(zs))]
    means, covariances = [filtered[-1][0]], [filtered[-1][1]]
    for m, P in reversed(filtered[:-1]):
        P_pred = A @ P @ A.T + Q
        G = P @ A.T @ np.linalg.inv(P_pred)
        means.append(m + G @ (means[-1] - A @ m))
        covariances.append(P + G @ (covariances[-1] - P_pred) @ G.T)
    return np.array(means[::-1]), np.array(covariances[::-1])


class LinearMixture(LinearGaussian):
    """s_t = A s_{t-1} + b_k + N(0, Q_k) with probability π_k, z_t = H s_t + N(0, R): a Gaussian-mixture transition
    (``step_components``, as the Lie prior's), linear; ``Q`` its moment-matched covariance."""

    def __init__(self, A, b, Qs, pi, H, R):
        self.b, self.Qs = torch.as_tensor(b, dtype=torch.float64), torch.as_tensor(Qs, dtype=torch.float64)
        self.pi = torch.as_tensor(pi, dtype=torch.float64)
        b_bar = self.pi @ self.b
        d = self.b - b_bar
        Q = torch.einsum("k,kij->ij", self.pi, self.Qs) + torch.einsum("k,ki,kj->ij", self.pi, d, d)
        super().__init__(A, Q, H, R)
        self.b_bar = b_bar

    def predict(self, s, generator):
        k = torch.multinomial(self.pi, len(s), replacement=True, generator=generator)
        noise = torch.randn(s.shape, generator=generator, dtype=s.dtype)
        return s @ self.A.T + self.b[k] + (torch.linalg.cholesky(self.Qs)[k] @ noise[..., None])[..., 0]

    def log_transition(self, s_next, s):
        terms = torch.stack([torch.distributions.MultivariateNormal(s @ self.A.T + b, Q).log_prob(s_next)
                             for b, Q in zip(self.b, self.Qs)], -1)
        return torch.logsumexp(terms + torch.log(self.pi), -1)

    def mean_step(self, s):
        return s @ self.A.T + self.b_bar

    def step_components(self, s, covariances=True, components=None):
        """ln π (B, K), the steps A s + b_k − s (B, K, n), the covariances Q_k (B, K, n, n) (None unless asked);
        with ``components`` (B, k) indices, those of each row."""
        steps = (s @ self.A.T - s)[:, None] + self.b[None]
        log_pi, Qs = torch.log(self.pi).expand(len(s), -1), self.Qs.expand(len(s), -1, -1, -1)
        if components is not None:
            log_pi, steps, Qs = (torch.gather(log_pi, 1, components), steps[torch.arange(len(s))[:, None], components],
                                 self.Qs[components])
        return log_pi, steps, Qs if covariances else None

    def step_weights(self, s):
        """ln π (B, K): the same at every state."""
        return torch.log(self.pi).expand(len(s), -1)

    def component_model(self):
        """A linear-Gaussian model running component ``k`` (set by the Gaussian-sum filter): s_t = A s + b_k + N(0, Q_k)."""
        return LinearComponent(self)


class LinearComponent(LinearGaussian):
    """One component of a :class:`LinearMixture`, chosen by ``k``."""

    def __init__(self, mixture: LinearMixture):
        super().__init__(mixture.A, mixture.Qs[0], mixture.H, mixture.R)
        self.mixture, self.k = mixture, 0

    def mean_step(self, s):
        return s @ self.A.T + self.mixture.b[self.k]

    def process_covariance(self, s):
        return self.mixture.Qs[self.k]


def sharp_model() -> LinearGaussian:
    """A constant-velocity state seen through a likelihood far narrower than the transition's step."""
    return LinearGaussian([[1, 1.0, 0], [0, 1, 0], [0, 0, 0.9]], np.diag([0.04, 0.04, 0.09]),
                          [[1.0, 0, 0], [0, 0, 1.0]], np.diag([0.001, 0.002]))


def sharp_frames(model):
    """Six frames z (6, 2) of ``model`` (one entry missing), the start's mean and covariance, and the Kalman filter's
    posterior mean and covariance after them."""
    zs = np.random.default_rng(0).normal(0, 1, (6, 2))
    zs[3, 0] = np.nan
    m0, P0 = np.array([0.5, -0.2, 1.0]), np.diag([0.3, 0.2, 0.5])
    return zs, m0, P0, *kalman(model, m0, P0, zs)
