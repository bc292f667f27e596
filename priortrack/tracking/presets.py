"""Filter presets: a TOML file names a filter, its prior and training motions, and the observation model.

A preset (the shipped ones: ``priortrack presets``; any path works too)::

    description = "particle filter, local Gaussian diffusion in joint-angle space"

    [filter]                      # kind, then that filter's own parameters
    kind = "pf"                   # pf | apf | ukf | ukf-sum | map
    particles = 1000

    [prior]
    kind = "diffusion-local"      # a kind of priortrack.priors.registry
    train = ["walkjog:35_0*"]     # motions as `load_motion` takes them (bundled patterns allowed)
    fps = 30.0
    options = { space = "angles" }   # keyword arguments of the kind's fit
    # file = "walk.npz"           # a prior written by `priortrack fit` instead of fitting one
    #                               (relative to the preset's folder; train then fits the global motion only)
    # defensive = 0.1             # mix in a fraction ε of local diffusion (priortrack.priors.defensive)
    # pose_state = true           # with 2+ cameras a GPDM's particles carry the pose beside x (priors.gpdm_pose)

    [observation]                 # JointLikelihood's parameters
    sigma_px = 10.0
    # one_camera_sigma_px = 10.0  # σ where one camera sees the person (default: sigma_px)

The valid keys of ``[filter]`` are the filter class's constructor parameters (besides the model
and the seed), those of ``[prior].options`` the kind's option schema
(:meth:`~priortrack.priors.registry.PriorKind.options`); anything else is a
:class:`PriortrackError` that lists the valid keys, and every value is checked for type and range.
Fitted priors are cached as prior files (no pickle) under :func:`cache_dir`, keyed by
:attr:`Preset.cache_key` and verified against a SHA-256 digest on load, so a second run does not refit.

The shipped presets' source is the repository's top-level ``filters/`` folder, installed as the
package data ``priortrack/experiments/preset_files/`` (pyproject.toml maps one onto the other).
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import logging
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from priortrack.data.bundled import expand_sources
from priortrack.data.load import load_motion
from priortrack.data.motion import Motion
from priortrack.device import resolve_device
from priortrack.errors import PriortrackError
from priortrack.filters.proposal import MIN_VIEWS
from priortrack.geometry.camera import PinholeCamera
from priortrack.models.tracking import TrackingModel
from priortrack.observation.likelihood import JointLikelihood
from priortrack.priors.base import DEFAULT_FPS, FORMAT_VERSION, TransitionModel, load_prior, prepare_motions
from priortrack.priors.cache import cache_dir, read_cached, write_cached
from priortrack.priors.defensive import DEFENSIVE_SPACES
from priortrack.priors.registry import PRIOR_KINDS, check_options, fit_prior, kinds_with

log = logging.getLogger(__name__)

#: Where the shipped presets live: the package data of an installed priortrack, else (a source
#: checkout, an editable install) the repository's top-level ``filters/`` folder.
PRESET_DIR = next((d for d in (Path(__file__).resolve().parent / "preset_files",
                               Path(__file__).resolve().parents[2] / "filters") if d.is_dir()),
                  Path(__file__).resolve().parent / "preset_files")
TOP_KEYS = ("description", "filter", "prior", "observation")
PRIOR_KEYS = ("kind", "train", "fps", "options", "annealing", "file", "defensive", "pose_state")
#: The [observation] key of the σ used where one camera sees the person (:attr:`Preset.one_camera_sigma_px`).
ONE_CAMERA = "one_camera_sigma_px"


#: Filter kind → (module, class). Each class says what it needs of a prior in ``requires``
#: (a capability of :mod:`priortrack.priors.registry`, or None for any prior).
FILTERS: dict[str, tuple[str, str]] = {
    "pf": ("priortrack.filters.particle", "ParticleFilter"),
    "apf": ("priortrack.filters.annealed", "AnnealedParticleFilter"),
    "ukf": ("priortrack.filters.ukf", "UnscentedFilter"),
    "ukf-sum": ("priortrack.filters.gaussian_sum", "GaussianSumFilter"),
    "map": ("priortrack.filters.map_tracker", "MapTracker"),
}


#: The filter kinds that run unscented filters (a Gaussian likelihood, R; the posterior-linearisation smoother).
UNSCENTED_KINDS = ("ukf", "ukf-sum")


def filter_class(kind: str) -> type:
    """The filter class of a preset's ``[filter] kind`` (imported on first use)."""
    module, name = FILTERS[kind]
    return getattr(importlib.import_module(module), name)


def _parameters(func: Callable, skip: tuple[str, ...]) -> dict[str, Any]:
    """A callable's keyword parameters and defaults, without ``skip``."""
    return {name: p.default for name, p in inspect.signature(func).parameters.items()
            if name not in skip and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def _check_keys(where: str, given: dict, valid) -> None:
    """Raise a PriortrackError naming the keys of ``given`` that are not in ``valid``, with the valid ones."""
    unknown = sorted(set(given) - set(valid))
    if unknown:
        raise PriortrackError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
                              f"valid keys: {', '.join(sorted(valid))}")


#: The largest count a preset may ask for (particles, layers, iterations, …).
MAX_COUNT = 10_000_000


def _check_types(where: str, given: dict, defaults: dict[str, Any]) -> None:
    """Each value must have its parameter's type, taken from the default: a whole number where the
    default is one (not a boolean, at most MAX_COUNT), a number where it is a float, text where it is
    text, true/false where it is a boolean; a parameter whose default is None takes a number."""
    for key, value in given.items():
        default = defaults.get(key)
        name = f"{where}: {key} = {value!r}"
        if isinstance(default, bool):
            ok, expected = isinstance(value, bool), "true or false"
        elif isinstance(default, int):
            ok = isinstance(value, int) and not isinstance(value, bool) and -1 <= value <= MAX_COUNT
            expected = f"a whole number up to {MAX_COUNT:,}"
        elif isinstance(default, float) or default is None:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            expected = "a finite number"
        elif isinstance(default, str):
            ok, expected = isinstance(value, str), "text"
        else:
            continue
        if not ok:
            raise PriortrackError(f"{name} must be {expected}")


@dataclass(frozen=True)
class Preset:
    """A parsed, validated preset.

    Attributes:
        name: the file's stem.
        filter_kind: a key of :data:`FILTERS`; filter_options: the filter's parameters.
        prior_kind, train (expanded sources), fps, prior_options: what the prior is fitted to.
        prior_file: a fitted prior to use instead of fitting one (``train`` then fits only the
            global motion), or None.
        annealing: the GPDM's dynamics annealing λ for filters that draw from it
            (:meth:`GPDM.annealed`; 1 = as learned); applied after fitting, not part of the cache key.
        defensive: ε of a :class:`~priortrack.priors.defensive.DefensiveMixture` with local diffusion
            fitted to the same motions in the prior's space (0: none).
        observation: JointLikelihood parameters (sigma_px, robust_nu).
        one_camera_sigma_px: σ in pixels where a single camera sees the person, or None (sigma_px): with two
            cameras or more the guided proposal draws where the detections are and meets the detector's σ; with
            one, the particles are the prior's draw, and 1000 of them resolve a wider likelihood better
            (:meth:`observation_for`).
        pose_state: where two cameras or more see the person, a GPDM's states carry the pose y beside the latent x
            (:class:`~priortrack.priors.gpdm_pose.PoseStateGPDM`), for the particle filters; with one camera the
            latent state alone (:meth:`prior`).
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
    prior_file: Path | None = None
    defensive: float = 0.0
    one_camera_sigma_px: float | None = None
    pose_state: bool = False

    @property
    def cache_key(self) -> str:
        """Hash of everything the fitted prior depends on: the kind, rate and options, the prior file
        format and priortrack's version, the training motions' content (names, channels, skeletons),
        and for the GPDM kinds torch's thread count (their L-BFGS paths part with the last digits of
        a multi-threaded sum)."""
        import torch

        from priortrack import __version__

        threads = torch.get_num_threads() if "latent" in PRIOR_KINDS[self.prior_kind].capabilities else None
        digest = hashlib.sha256(json.dumps([self.prior_kind, self.fps, self.prior_options, FORMAT_VERSION, __version__,
                                            threads], sort_keys=True).encode())
        for motion in self.training_motions:
            digest.update(motion.name.encode())
            for array in (motion.channels, motion.skeleton.offsets, motion.skeleton.rot_axes):
                digest.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())
        return digest.hexdigest()[:24]

    def prior(self, cache: Path | None = None, progress=None, cameras: int = 1) -> TransitionModel:
        """The prior for a recording from ``cameras`` cameras: the preset's prior file, else the fitted prior from the
        cache if it is there (fitted and cached otherwise); with ``defensive`` ε, mixed with local diffusion; with
        ``pose_state`` and two cameras or more, the GPDM with the pose in its state. One camera keeps the latent
        state: the particles are the prior's draw there, and a pose drawn about the manifold, which one view cannot
        pin, tracked worse (eval people, lab bench, held-out people, mm: 90 → 164 on 07, 64 → 103 on 08+39)."""
        prior = self._learned_prior(cache, progress)
        if self.pose_state and cameras >= MIN_VIEWS:
            from priortrack.priors.gpdm_pose import PoseStateGPDM

            return PoseStateGPDM(prior)
        if self.defensive == 0:
            return prior
        from priortrack.priors.defensive import DefensiveMixture

        space = DEFENSIVE_SPACES.get(type(prior.space).__name__)
        if space is None:
            raise PriortrackError(f"preset {self.name!r}: [prior] defensive mixes in diffusion on the prior's own "
                                  f"state space; the {self.prior_kind} prior's ({type(prior.space).__name__}) has none")
        fallback = replace(self, prior_kind="diffusion-local", prior_options={"space": space}, annealing=1.0,
                           prior_file=None, defensive=0.0).prior(cache)
        return DefensiveMixture(prior, fallback, self.defensive)

    def prior_path(self, cache: Path | None = None) -> Path:
        """Where the prior cache keeps the preset's fitted prior (its ``file`` where it names one)."""
        if self.prior_file is not None:
            return Path(self.prior_file)
        return (cache_dir() if cache is None else Path(cache)) / f"{self.prior_kind}-{self.cache_key}.npz"

    def _learned_prior(self, cache: Path | None, progress) -> TransitionModel:
        if self.prior_file is not None:
            prior = load_prior(self.prior_file)
            if prior.kind != self.prior_kind:
                raise PriortrackError(f"preset {self.name!r}: [prior] file {self.prior_file} holds a {prior.kind!r} "
                                      f"prior, not {self.prior_kind!r}")
            return prior if self.annealing == 1.0 else prior.annealed(self.annealing)
        path = self.prior_path(cache)
        prior = read_cached(path, load_prior)
        if prior is None:
            prior = fit_prior(self.prior_kind, self.training_motions, progress=progress, fps=self.fps,
                              **self.prior_options)
            write_cached(path, prior.save, f"{prior.kind} prior")
        return prior if self.annealing == 1.0 else prior.annealed(self.annealing)

    @cached_property
    def training_motions(self) -> tuple[Motion, ...]:
        """The ``train`` motions at the prior's rate, loaded once per preset (a table reuses them
        for the global motion of every run)."""
        return tuple(prepare_motions([load_motion(source) for source in self.train], self.fps))

    def observation_for(self, cameras: int) -> dict[str, Any]:
        """The observation model's parameters for a recording from ``cameras`` cameras: :attr:`observation`,
        with σ = :attr:`one_camera_sigma_px` where there is one camera and the preset gives it."""
        if cameras == 1 and self.one_camera_sigma_px is not None:
            return {**self.observation, "sigma_px": self.one_camera_sigma_px}
        return dict(self.observation)

    def likelihood(self, camera: PinholeCamera) -> JointLikelihood:
        """The single-camera likelihood (:meth:`observation_for` one camera)."""
        return JointLikelihood(camera, **self.observation_for(1))

    def model(self, camera: PinholeCamera, cache: Path | None = None, progress=None) -> TrackingModel:
        """The tracking model: the prior, the global motion fitted to the training motions, the likelihood."""
        return TrackingModel.fitted(self.prior(cache, progress), self.training_motions, self.likelihood(camera))

    def build(self, camera: PinholeCamera, seed: int = 0, cache: Path | None = None, progress=None,
              device: str = "cpu"):
        """The filter on the synthetic single-camera model, ready to ``run(observations, motion)``."""
        return self.filter_for(self.model(camera, cache, progress), seed, device)

    def filter_for(self, model, seed: int = 0, device: str = "cpu"):
        """The preset's filter, with its parameters, on ``model``; on ``device`` where the filter takes
        one (the particle filters); the unscented filter and the MAP tracker run on the CPU (their
        sigma points and windows are few; filterpy's and scipy's updates are numpy), and refuse another."""
        cls = filter_class(self.filter_kind)
        parameters = inspect.signature(cls.__init__).parameters
        given = {"seed": seed} if "seed" in parameters else {}                 # the UKF is deterministic
        if "device" in parameters:
            given["device"] = device
        elif resolve_device(device).type != "cpu":
            raise PriortrackError(f"preset {self.name!r}: its {cls.__name__} runs on the CPU only (numpy updates of "
                                  f"a few points); --device {device} is for the particle filters (pf, apf)")
        return cls(model, **given, **self.filter_options)


def preset_names() -> list[str]:
    """The shipped presets (stems of the TOML files in :data:`PRESET_DIR`)."""
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
    return parse_preset(table, path.stem, str(path), folder=path.parent)


def parse_preset(table: dict, name: str, where: str = "preset", folder: Path | None = None) -> Preset:
    """Validate a preset's parsed TOML ``table``; a ``[prior] file`` is relative to ``folder``
    (the preset's own folder; the working directory if None)."""
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
    prior_file = _prior_file(prior, where, folder)
    prior_kind, fps = prior.get("kind"), prior.get("fps", DEFAULT_FPS)
    if prior_file is not None:                  # the file says what it holds (and is checked on the way)
        stored = load_prior(prior_file)
        if prior_kind not in (None, stored.kind):
            raise PriortrackError(f"{where}: [prior] kind {prior_kind!r}, but its file {prior_file} holds a "
                                  f"{stored.kind!r} prior")
        prior_kind, fps = stored.kind, stored.fps
    if prior_kind not in PRIOR_KINDS:
        raise PriortrackError(f"{where}: [prior] kind {prior_kind!r} is not one of {', '.join(PRIOR_KINDS)}")
    cls = filter_class(kind)
    if cls.requires is not None and cls.requires not in PRIOR_KINDS[prior_kind].capabilities:
        raise PriortrackError(f"{where}: filter {kind!r} cannot run a {prior_kind!r} prior; it runs "
                              f"{', '.join(kinds_with(cls.requires))}")
    valid = _parameters(cls.__init__, ("self", "model", "seed", "device"))
    _check_keys(f"{where} [filter] ({kind})", options, ["kind", *valid])
    _check_types(f"{where} [filter]", options, valid)
    train = prior.get("train")
    if not isinstance(train, list) or not train or not all(isinstance(s, str) for s in train):
        raise PriortrackError(f"{where}: [prior] train must be a non-empty list of motion names or paths")
    prior_options = dict(prior.get("options", {}))
    check_options(prior_kind, prior_options, PRIOR_KINDS[prior_kind].options(), f"{where} [prior] options")
    _check_types(f"{where} [prior] options", prior_options, PRIOR_KINDS[prior_kind].options())

    annealing = prior.get("annealing", 1.0)
    if "annealing" in prior:
        gpdm = kinds_with("latent")
        if prior_kind not in gpdm or kind == "map":
            raise PriortrackError(f"{where}: [prior] annealing is the GPDM's dynamics annealing for the filters that "
                                  f"draw from it (pf, apf, ukf with {' or '.join(gpdm)}); the MAP tracker takes "
                                  f"its own [filter] annealing")
        if isinstance(annealing, bool) or not isinstance(annealing, (int, float)) or not 0 < annealing <= 1:
            raise PriortrackError(f"{where}: [prior] annealing must be a number in (0, 1], got {annealing!r}")

    defensive = prior.get("defensive", 0.0)
    if isinstance(defensive, bool) or not isinstance(defensive, (int, float)) or not 0 <= defensive < 1:
        raise PriortrackError(f"{where}: [prior] defensive must be a fraction in [0, 1), got {defensive!r}")

    pose_state = prior.get("pose_state", False)
    if not isinstance(pose_state, bool):
        raise PriortrackError(f"{where}: [prior] pose_state must be true or false, got {pose_state!r}")
    if pose_state and (prior_kind not in kinds_with("latent") or kind not in ("pf", "apf") or defensive):
        raise PriortrackError(f"{where}: [prior] pose_state puts the pose in a GPDM's particles (filters pf, apf with "
                              f"{' or '.join(kinds_with('latent'))}, no defensive share); here: {kind} with {prior_kind}"
                              + (f", defensive {defensive}" if defensive else ""))

    observation = dict(table.get("observation", {}))
    _check_keys(f"{where} [observation]", observation,
                [*_parameters(JointLikelihood.__init__, ("self", "camera")), ONE_CAMERA])
    _check_types(f"{where} [observation]", observation, {"sigma_px": 10.0, "robust_nu": 4.0, ONE_CAMERA: 10.0})
    one_camera = observation.pop(ONE_CAMERA, None)
    if one_camera is not None and not one_camera > 0:
        raise PriortrackError(f"{where} [observation]: {ONE_CAMERA} must be positive pixels, got {one_camera!r}")
    return Preset(name, str(table.get("description", "")), kind, options, prior_kind,
                  tuple(expand_sources(train)), float(fps), prior_options, observation,
                  float(annealing), prior_file, float(defensive), None if one_camera is None else float(one_camera),
                  pose_state)


def _prior_file(prior: dict, where: str, folder: Path | None) -> Path | None:
    """``[prior] file`` resolved against ``folder``; with it, fitting keys are an error."""
    if "file" not in prior:
        return None
    if not isinstance(prior["file"], str) or not prior["file"]:
        raise PriortrackError(f"{where}: [prior] file must be the path of a prior file, got {prior['file']!r}")
    fitting = sorted({"options", "fps"} & set(prior))
    if fitting:
        raise PriortrackError(f"{where}: [prior] file names a fitted prior; {', '.join(fitting)} "
                              f"{'is' if len(fitting) == 1 else 'are'} for fitting one and cannot go with it")
    path = Path(prior["file"]).expanduser()
    path = path if path.is_absolute() or folder is None else Path(folder) / path
    if not path.is_file():
        raise PriortrackError(f"{where}: [prior] file {path} does not exist")
    return path
