"""Filter presets: a TOML file names a filter, its prior and training motions, and the observation model.

A preset (the top-level ``filters/`` folder holds the shipped ones; any path works too)::

    description = "particle filter, local Gaussian diffusion in joint-angle space"

    [filter]                      # kind, then that filter's own parameters
    kind = "pf"                   # pf | apf | ukf | map
    particles = 1000

    [prior]
    kind = "diffusion-local"      # a kind of priortrack.priors.FIT_KINDS
    train = ["walkjog:35_0*"]     # motions as `load_motion` takes them (bundled patterns allowed)
    fps = 30.0
    options = { space = "angles" }   # keyword arguments of the kind's fit

    [observation]                 # JointLikelihood's parameters
    sigma_px = 10.0

The valid keys of ``[filter]`` are the filter class's constructor parameters (besides the model
and the seed), those of ``[prior].options`` the prior's ``fit`` parameters; anything else is a
:class:`PriortrackError` that lists the valid keys. Fitted priors are cached as prior files
(no pickle) under :func:`cache_dir`, keyed by a hash of the ``[prior]`` table, the expanded
training sources and the prior file format, so a second run does not refit.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import logging
import os
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from priortrack.data.bundled import expand_sources
from priortrack.data.load import load_motion
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors.base import DEFAULT_FPS, FORMAT_VERSION, TransitionModel, load_prior, prepare_motions
from priortrack.priors.fit import FIT_KINDS, fit_prior
from priortrack.priors.global_motion import GlobalMotion

log = logging.getLogger(__name__)

#: Where the shipped presets live: the repository's top-level ``filters/`` folder.
PRESET_DIR = Path(__file__).resolve().parents[2] / "filters"
TOP_KEYS = ("description", "filter", "prior", "observation")
PRIOR_KEYS = ("kind", "train", "fps", "options", "annealing")
GPDM_KINDS = ("gpdm", "bgpdm")
GAUSSIAN_KINDS = ("diffusion-global", "diffusion-local", "gpdm", "bgpdm")


#: Filter kind → (module, class, the prior kinds it can run).
FILTERS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "pf": ("priortrack.filters.particle", "ParticleFilter", FIT_KINDS),
    "apf": ("priortrack.filters.annealed", "AnnealedParticleFilter", FIT_KINDS),
    "ukf": ("priortrack.filters.ukf", "UnscentedFilter", GAUSSIAN_KINDS),
    "map": ("priortrack.filters.map_tracker", "MapTracker", GPDM_KINDS),
}


def filter_class(kind: str) -> type:
    """The filter class of a preset's ``[filter] kind`` (imported on first use)."""
    module, name, _ = FILTERS[kind]
    return getattr(importlib.import_module(module), name)


def _parameters(func: Callable, skip: tuple[str, ...]) -> dict[str, Any]:
    """A callable's keyword parameters and defaults, without ``skip``."""
    return {name: p.default for name, p in inspect.signature(func).parameters.items()
            if name not in skip and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def _check_keys(where: str, given: dict, valid) -> None:
    unknown = sorted(set(given) - set(valid))
    if unknown:
        raise PriortrackError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
                              f"valid keys: {', '.join(sorted(valid))}")


@dataclass(frozen=True)
class Preset:
    """A parsed, validated preset.

    Attributes:
        name: the file's stem.
        filter_kind: "pf", "apf", "ukf" or "map"; filter_options: the filter's parameters.
        prior_kind, train (expanded sources), fps, prior_options: what the prior is fitted to.
        annealing: the GPDM's dynamics annealing λ for filters that draw from it
            (:meth:`GPDM.annealed`; 1 = as learned); applied after fitting, not part of the cache key.
        observation: JointLikelihood parameters (sigma_px, robust_nu).
    """

    name: str
    description: str
    filter_kind: str
    filter_options: dict[str, Any] = field(default_factory=dict)
    prior_kind: str = "diffusion-local"
    train: tuple[str, ...] = ()
    fps: float = DEFAULT_FPS
    prior_options: dict[str, Any] = field(default_factory=dict)
    observation: dict[str, Any] = field(default_factory=dict)
    annealing: float = 1.0

    @property
    def cache_key(self) -> str:
        """Hash of everything the fitted prior depends on."""
        text = json.dumps([self.prior_kind, list(self.train), self.fps, self.prior_options, FORMAT_VERSION],
                          sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def prior(self, cache: Path | None = None, progress=None) -> TransitionModel:
        """The fitted prior, from the cache if it is there (fitted and cached otherwise)."""
        cache = cache_dir() if cache is None else Path(cache)
        path = cache / f"{self.prior_kind}-{self.cache_key}.npz"
        if path.exists():
            log.info("prior from cache %s", path)
            prior = load_prior(path)
        else:
            prior = fit_prior(self.prior_kind, self.training_motions, progress=progress, fps=self.fps,
                              **self.prior_options)
            try:                          # a cache that cannot be written costs the next run a refit, no more
                cache.mkdir(parents=True, exist_ok=True)
                partial = path.with_suffix(".partial.npz")
                prior.save(partial)
                partial.replace(path)
                log.info("fitted %s prior cached at %s", self.prior_kind, path)
            except (PriortrackError, OSError) as exc:
                log.warning("fitted %s prior not cached (%s)", self.prior_kind, exc)
        return prior if self.annealing == 1.0 else prior.annealed(self.annealing)

    @cached_property
    def training_motions(self) -> tuple[Motion, ...]:
        """The ``train`` motions at the prior's rate, loaded once per preset (a table reuses them
        for the global motion of every run)."""
        return tuple(prepare_motions([load_motion(source) for source in self.train], self.fps))

    def global_motion(self, prior: TransitionModel) -> GlobalMotion:
        """The placement model (position and heading second order, tilt AR(1)), fitted to the
        training motions' placements."""
        return GlobalMotion.fit([prior.space.global_pose(m) for m in self.training_motions])

    def likelihood(self, camera: PinholeCamera) -> JointLikelihood:
        return JointLikelihood(camera, **self.observation)

    def build(self, camera: PinholeCamera, seed: int = 0, cache: Path | None = None, progress=None):
        """The filter, ready to ``run(observations, motion)``."""
        from priortrack.filters.tracking_model import TrackingModel

        prior = self.prior(cache, progress)
        model = TrackingModel(prior, self.global_motion(prior), self.likelihood(camera))
        cls = filter_class(self.filter_kind)
        seeded = {"seed": seed} if "seed" in inspect.signature(cls.__init__).parameters else {}  # the UKF is deterministic
        return cls(model, **seeded, **self.filter_options)


def cache_dir() -> Path:
    """``$PRIORTRACK_CACHE``, else ``$XDG_CACHE_HOME/priortrack/priors``, else ``~/.cache/priortrack/priors``."""
    if os.environ.get("PRIORTRACK_CACHE"):
        return Path(os.environ["PRIORTRACK_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "priortrack" / "priors"


def preset_names() -> list[str]:
    """The shipped presets (stems of ``filters/*.toml``)."""
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def preset_path(name: str | Path) -> Path:
    """A preset file: an existing path, or a shipped preset's name."""
    path = Path(name)
    if path.suffix == ".toml" and path.exists():
        return path
    shipped = PRESET_DIR / f"{name}.toml"
    if shipped.exists():
        return shipped
    raise PriortrackError(f"no preset {str(name)!r}: give a .toml path or one of {', '.join(preset_names())}")


def load_preset(name: str | Path) -> Preset:
    """Read and validate a preset (see the module docstring)."""
    path = preset_path(name)
    try:
        table = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise PriortrackError(f"{path}: not valid TOML: {exc}") from None
    return parse_preset(table, path.stem, str(path))


def parse_preset(table: dict, name: str, where: str = "preset") -> Preset:
    """Validate a preset's parsed TOML ``table``."""
    _check_keys(where, table, TOP_KEYS)
    for section in ("filter", "prior"):
        if not isinstance(table.get(section), dict):
            raise PriortrackError(f"{where}: a [{section}] table is required")
    options = dict(table["filter"])
    kind = options.pop("kind", None)
    if kind not in FILTERS:
        raise PriortrackError(f"{where}: [filter] kind {kind!r} is not one of {', '.join(FILTERS)}")
    prior = table["prior"]
    _check_keys(f"{where} [prior]", prior, PRIOR_KEYS)
    prior_kind = prior.get("kind")
    if prior_kind not in FIT_KINDS:
        raise PriortrackError(f"{where}: [prior] kind {prior_kind!r} is not one of {', '.join(FIT_KINDS)}")
    usable = FILTERS[kind][2]
    if prior_kind not in usable:
        raise PriortrackError(f"{where}: filter {kind!r} cannot run a {prior_kind!r} prior; it runs {', '.join(usable)}")
    valid = _parameters(filter_class(kind).__init__, ("self", "model", "seed"))
    _check_keys(f"{where} [filter] ({kind})", options, ["kind", *valid])
    train = prior.get("train")
    if not isinstance(train, list) or not train or not all(isinstance(s, str) for s in train):
        raise PriortrackError(f"{where}: [prior] train must be a non-empty list of motion names or paths")
    prior_options = dict(prior.get("options", {}))
    _check_keys(f"{where} [prior] options ({prior_kind})", prior_options, _fit_parameters(prior_kind))

    annealing = prior.get("annealing", 1.0)
    if "annealing" in prior:
        if prior_kind not in GPDM_KINDS or kind == "map":
            raise PriortrackError(f"{where}: [prior] annealing is the GPDM's dynamics annealing for the filters that "
                                  f"draw from it (pf, apf, ukf with {' or '.join(GPDM_KINDS)}); the MAP tracker takes "
                                  f"its own [filter] annealing")
        if isinstance(annealing, bool) or not isinstance(annealing, (int, float)) or not 0 < annealing <= 1:
            raise PriortrackError(f"{where}: [prior] annealing must be a number in (0, 1], got {annealing!r}")

    observation = dict(table.get("observation", {}))
    _check_keys(f"{where} [observation]", observation, _parameters(JointLikelihood.__init__, ("self", "camera")))
    return Preset(name, str(table.get("description", "")), kind, options, prior_kind,
                  tuple(expand_sources(train)), float(prior.get("fps", DEFAULT_FPS)), prior_options, observation,
                  float(annealing))


def _fit_parameters(kind: str) -> list[str]:
    from priortrack.priors.diffusion import Diffusion
    from priortrack.priors.gpdm import GPDM
    from priortrack.priors.lie import LiePrior

    fit = {"diffusion-global": Diffusion.fit, "diffusion-local": Diffusion.fit, "gpdm": GPDM.fit,
           "bgpdm": GPDM.fit, "lie": LiePrior.fit}[kind]
    # fit_prior sets these itself.
    return list(_parameters(fit, ("cls", "motions", "local", "balanced", "progress", "fps")))
