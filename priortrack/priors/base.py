"""The transition-model contract and the prior file format.

Every prior is a transition model over states ``(P, S)`` of its :mod:`state space
<priortrack.priors.spaces>` (DESIGN.md):

- ``sample(x, generator)`` draws x_t for every row of x_{t-1};
- ``log_prob(x_next, x)`` scores log p(x_t | x_{t-1}) per row, (P,);
- ``mean(x)`` is the deterministic mean step (the unscented filter's fx);
- ``initial(x0, n, generator)`` draws n starting states around a known first state;
- ``joints(x)`` decodes states to eval15 joints (P, 15, 3), metres;
- ``encode(motion)`` gives the states of a motion's frames (at the prior's frame rate).

A prior learns and runs at one frame rate (``fps``, default 30): motions at other rates are
resampled on the way in. It is saved to one ``.npz`` (no pickle) holding its arrays and a
JSON header with the format version, its kind and the preprocessing it used.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from priortrack.data.motion import Motion
from priortrack.data.npz import read_npz
from priortrack.errors import PriortrackError
from priortrack.output import output_path
from priortrack.priors.registry import PRIOR_KINDS
from priortrack.priors.spaces import StateSpace

FORMAT = "priortrack-prior"
FORMAT_VERSION = 1
DEFAULT_FPS = 30.0

class TransitionModel(ABC):
    """Base of every prior. Subclasses set ``kind``, ``space`` and ``fps``."""

    kind: str
    space: StateSpace
    fps: float
    #: The fit's final objective: the negative log-likelihood per step (diffusion), the
    #: negative log posterior (GPDM), the message length (Lie mixture).
    objective: float = float("nan")

    @property
    def state_dim(self) -> int:
        return self.space.dim

    # ---- the contract ------------------------------------------------------------------
    @abstractmethod
    def sample(self, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(P, S) → (P, S), one draw of x_t ~ p(x_t | x_{t-1}) per row."""

    @abstractmethod
    def log_prob(self, x_next: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """(P, S), (P, S) → (P,) log p(x_next | x)."""

    @abstractmethod
    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, S), the mean (or mode) of p(x_t | x_{t-1})."""

    def step_weights(self, x) -> torch.Tensor:
        """ln π (P, K) of :meth:`step_components` alone: one component, weight 1."""
        return torch.zeros((len(x), 1), dtype=torch.float64, device=torch.as_tensor(x).device)

    def step_components(self, x, covariances: bool = True, components: torch.Tensor | None = None):
        """The transition as a mixture of Gaussian steps in the tangent coordinates of ``space.local`` at each
        state x (P, S): ln π (P, K), the component means (P, K, n) and covariances (P, K, n, n) (None unless
        ``covariances``) (what the particle filter's guided proposal linearises: :mod:`priortrack.filters.proposal`).
        A Gaussian transition is one component, the mean step mean(x) ⊟ x and ``transition_covariance(x)`` (its
        ``components`` (P, k) indices all 0); the Lie mixture overrides it."""
        x = self.check_state(x)
        covariance = getattr(self, "transition_covariance", None)
        if covariance is None:
            raise PriortrackError(f"the {self.kind} prior has no Gaussian step (no transition_covariance)")
        k = 1 if components is None else components.shape[1]
        step = self.space.local(self.mean(x), x)[:, None].expand(-1, k, -1)
        return (x.new_zeros(len(x), k, dtype=torch.float64), step,
                covariance(x)[:, None].expand(-1, k, -1, -1) if covariances else None)

    def initial(self, x0, n: int, generator: torch.Generator) -> torch.Tensor:
        """(S,) known first state → (n, S) states drawn around it with the prior's own
        one-step spread: the first row is x0 itself, the others one transition from it; drawn on the
        generator's device."""
        x0 = self.check_state(torch.as_tensor(x0).reshape(1, -1), "x0").to(generator.device)
        if n < 1:
            raise PriortrackError(f"initial: n must be positive, got {n}")
        drawn = self.sample(x0.expand(n, -1).contiguous(), generator)
        drawn[0] = x0[0]
        return drawn

    def joints(self, x: torch.Tensor) -> torch.Tensor:
        """(P, S) → (P, 15, 3) eval15 joints in metres (pelvis-centred body frame)."""
        return self.space.joints(self.check_state(x))

    def encode(self, motion: Motion) -> torch.Tensor:
        """(T, S) float64 states of a motion, resampled to the prior's frame rate."""
        return self.space.encode(motion if motion.fps == self.fps else motion.resample(self.fps))

    # ---- checks --------------------------------------------------------------------------
    def check_state(self, x, name: str = "state") -> torch.Tensor:
        """Raise a PriortrackError unless x is a (P, S) tensor of points of the state space
        (:meth:`~priortrack.priors.spaces.StateSpace.check_points`) without NaN or inf.
        The finiteness test runs on x's minimum and maximum (both propagate NaN): one pass
        without a temporary, as this sits on every filter's sampling path."""
        x = torch.as_tensor(x)
        if x.dim() != 2 or x.shape[1] != self.state_dim:
            raise PriortrackError(f"{name} has shape {tuple(x.shape)}; expected (P, {self.state_dim}) "
                                  f"for a {self.kind} prior")
        if x.numel() and not bool(torch.isfinite(torch.stack(torch.aminmax(x))).all()):
            raise PriortrackError(f"{name} contains NaN or inf")
        self.space.check_points(x, name)
        return x

    def check_pair(self, x_next, x) -> tuple[torch.Tensor, torch.Tensor]:
        """(x_next, x) checked as states, and as rows of the same transitions (same P)."""
        x = self.check_state(x)
        x_next = self.check_state(x_next, "x_next")
        if x_next.shape[0] != x.shape[0]:
            raise PriortrackError(f"x_next has {x_next.shape[0]} rows and x {x.shape[0]}; "
                                  f"log_prob scores one transition per row")
        return x_next, x

    # ---- files ---------------------------------------------------------------------------
    @abstractmethod
    def _arrays(self) -> dict[str, np.ndarray]:
        """The model's own arrays (the space's are added by :meth:`save`)."""

    @abstractmethod
    def _header(self) -> dict:
        """The model's own JSON-able settings and fit summary."""

    @classmethod
    @abstractmethod
    def _restore(cls, arrays: dict[str, np.ndarray], header: dict) -> TransitionModel:
        """Rebuild from what :meth:`save` wrote."""

    def save(self, path: str | Path) -> Path:
        """Write the prior to ``path`` (npz: arrays + a JSON header, no pickle)."""
        header = {"format": FORMAT, "version": FORMAT_VERSION, "kind": self.kind, "fps": self.fps,
                  "space": type(self.space).__name__, **self._header()}
        path = output_path(path, "prior file")
        with open(path, "wb") as f:
            np.savez(f, header=np.array(json.dumps(header)), **self.space.to_arrays(), **self._arrays())
        return path


#: The most a prior file's arrays may hold together, bytes (the bundled presets' largest is ~3 MB).
MAX_PRIOR_BYTES = 1 << 30
#: Header fields every kind reads, with their types; the kinds' own are checked in :data:`HEADER_TYPES`.
HEADER_TYPES = {"fps": (int, float), "local": bool, "balanced": bool, "space": str, "scale": (int, float),
                "objective": (int, float), "message_length": (int, float), "log_likelihood": (int, float),
                "train_frames": int, "fit": dict}


class _Shared:
    """The attribute of that name of the prior a :class:`BuiltOnPrior` is built on. A descriptor on the class, not
    ``__getattr__``: Python 3.12's ``isinstance`` against a runtime-checkable protocol looks attributes up statically
    (``inspect.getattr_static``), and would not see a forwarded one."""

    def __init__(self, name: str):
        self.name = name

    def __get__(self, transition, owner=None):
        if transition is None:
            return self
        return getattr(getattr(transition, transition.BASE), self.name)


class BuiltOnPrior:
    """A transition built on another prior (the attribute named by ``BASE``): that prior's state space, start and
    name (``SHARED``) are read from it, the transition's own methods (a draw, a density, a mean step, a covariance)
    are the subclass's (:class:`~priortrack.priors.defensive.DefensiveMixture`,
    :class:`~priortrack.priors.component.ComponentTransition`)."""

    #: The attribute holding the prior built on.
    BASE = "base"
    #: What is that prior's: the state space and the start.
    SHARED = ("kind", "space", "fps", "state_dim", "encode", "joints", "initial", "check_state", "check_pair")
    #: The transition's name in an error.
    WHAT = "a transition built on a prior"

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for name in cls.SHARED:
            if name not in cls.__dict__:
                setattr(cls, name, _Shared(name))

    def __getattr__(self, name: str):
        raise AttributeError(f"{self.WHAT} has no {name!r}")


def load_prior(path: str | Path) -> TransitionModel:
    """Load a prior written by :meth:`TransitionModel.save`; a clear error for a file of
    another format or version, a truncated file, an unknown kind, arrays of objects or of absurd
    sizes (checked from their headers before any is read) and header fields of the wrong type."""
    path = Path(path)
    if not path.exists():
        raise PriortrackError(f"prior file {path} does not exist")
    arrays = read_npz(path, MAX_PRIOR_BYTES, "prior file")
    if "header" not in arrays:
        raise PriortrackError(f"{path} is not a priortrack prior (no header)")
    try:
        header = json.loads(str(arrays.pop("header")))
    except json.JSONDecodeError as exc:
        raise PriortrackError(f"{path} is not a priortrack prior (its header is not JSON: {exc})") from None
    if not isinstance(header, dict):
        raise PriortrackError(f"{path} is not a priortrack prior (its header is a {type(header).__name__}, "
                              f"not a JSON object)")
    if header.get("format") != FORMAT:
        raise PriortrackError(f"{path} is not a priortrack prior (format {header.get('format')!r})")
    if header.get("version") != FORMAT_VERSION:
        raise PriortrackError(f"{path}: prior format version {header.get('version')!r} is not supported "
                              f"(this priortrack reads version {FORMAT_VERSION})")
    for field, types in HEADER_TYPES.items():
        value = header.get(field)
        if field in header and (not isinstance(value, types) or (types is not bool and isinstance(value, bool))):
            raise PriortrackError(f"{path}: header field {field!r} is {value!r}, not of its type")
    if "fps" in header and not 0 < header["fps"] < 1e4:
        raise PriortrackError(f"{path}: header fps {header['fps']!r} is not a frame rate")
    kind = header.get("kind")
    if kind not in PRIOR_KINDS:
        raise PriortrackError(f"{path}: unknown prior kind {kind!r}; kinds: {', '.join(PRIOR_KINDS)}")
    try:
        prior = PRIOR_KINDS[kind].prior_class()._restore(arrays, header)
    except KeyError as exc:
        raise PriortrackError(f"{path}: the {kind} prior lacks {exc.args[0]!r}") from None
    except (ValueError, TypeError, IndexError, RuntimeError, StopIteration) as exc:
        raise PriortrackError(f"{path}: the {kind} prior's arrays do not fit together ({exc})") from None
    return prior


def prepare_motions(motions: Sequence[Motion], fps: float, min_frames: int = 3) -> list[Motion]:
    """Resample training motions to ``fps`` and check them (enough frames, no NaN)."""
    if not motions:
        raise PriortrackError("no training motions given")
    prepared = []
    for m in motions:
        if not np.isfinite(m.channels).all():
            raise PriortrackError(f"training motion {m.name!r} contains NaN or inf")
        m = m if m.fps == fps else m.resample(fps)
        if len(m) < min_frames:
            raise PriortrackError(f"training motion {m.name!r} has {len(m)} frames at {fps:g} fps; "
                                  f"at least {min_frames} are needed")
        prepared.append(m)
    return prepared


def generator_for(seed: int | torch.Generator, device: str | torch.device = "cpu") -> torch.Generator:
    """A torch generator from a seed (or the generator itself)."""
    if isinstance(seed, torch.Generator):
        return seed
    return torch.Generator(device=device).manual_seed(int(seed))
