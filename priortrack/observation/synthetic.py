"""Synthetic 2D observations: project 3D joints through a camera, then corrupt them.

Pipeline of :func:`synthesize` for positions X (T, 15, 3) metres (eval15 order, world Y-up):

    uv_clean[t, j] = project(camera, X[t, j])      NaN if behind the camera (Z_c <= 1e-6)
    uv_clean[t, j] = NaN                           for joints j not in ``joints``
    uv = uv_clean + sigma_px * n,  n ~ N(0, I)     (every observed entry, every scenario)
    uv = scenario(uv)                              (drop spans, occlude, replace by outliers)

Missing observations are NaN: they are data, not errors.  Points that project outside
the image are kept (use :func:`default_camera` to keep the subject in view).

Scenarios (see ``SCENARIOS``; every one also takes ``sigma_px``):

* ``clean``     - no corruption (sigma_px default 0).
* ``noise``     - Gaussian pixel noise, sigma_px default 5.
* ``dropout``   - per-joint missing spans from a Poisson process.
* ``occlusion`` - every observed joint but the head missing for an interval (the shrub
  of the GPDM paper, Urtasun et al. 2006).
* ``blackout``  - every joint missing for about one gait cycle.
* ``outliers``  - a fraction of detections thrown far away.

Randomness comes from ``numpy.random.default_rng(seed)`` only; the same seed gives the
same observations.
"""

from __future__ import annotations

import json
import logging
import math
import os
import types
import zipfile
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np
import torch

from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.errors import PriortrackError
from priortrack.geometry.camera import PinholeCamera
from priortrack.output import output_path

__all__ = [
    "EVAL15_NAMES",
    "PAPER_OBSERVED",
    "FORMAT_VERSION",
    "SCENARIOS",
    "ScenarioSpec",
    "Observations",
    "synthesize",
    "parse_scenario",
    "default_camera",
]

logger = logging.getLogger(__name__)

_N_JOINTS = len(EVAL15_NAMES)
_HEAD = EVAL15_NAMES.index("head")

#: The paper's observed joints (Urtasun, Fleet & Fua, CVPR 2006: "head, left shoulder,
#: left hand, both knees, both feet and the pelvis").  The paper says "nine" joints but
#: lists these eight; we use the eight listed, with hand -> wrist and foot -> ankle.
PAPER_OBSERVED: tuple[str, ...] = ("head", "lshoulder", "lwrist", "lknee", "rknee", "lankle", "rankle", "pelvis")

#: Version of the npz layout written by :meth:`Observations.save`.
FORMAT_VERSION = 1

_META_KEYS = ("format_version", "joints", "scenario", "params", "seed", "fps", "camera")


class ScenarioSpec(NamedTuple):
    """A registry entry: ``defaults`` (read-only name -> default value) and ``doc``."""

    defaults: Mapping[str, Any]
    doc: str


def _spec(defaults: dict[str, Any], doc: str) -> ScenarioSpec:
    return ScenarioSpec(types.MappingProxyType(dict(defaults)), doc)


#: Scenario registry: name -> (defaults, docstring).  ``start_s`` = None means one third
#: of the clip duration.  Intervals cover frames round(start_s*fps) ... round(start_s*fps)
#: + max(1, round(length_s*fps)) - 1, clipped to the clip.
SCENARIOS: Mapping[str, ScenarioSpec] = types.MappingProxyType(
    {
        "clean": _spec(
            {"sigma_px": 0.0},
            "Projected joints as they are (optionally sigma_px Gaussian pixel noise, default 0).",
        ),
        "noise": _spec(
            {"sigma_px": 5.0},
            "Gaussian pixel noise uv + sigma_px * N(0, I) on every observed entry (default 5 px).",
        ),
        "dropout": _spec(
            {"sigma_px": 0.0, "rate_per_s": 0.5, "min_frames": 3, "max_frames": 15},
            "Per-joint missing spans: span starts form a Poisson process of rate_per_s spans per "
            "joint per second (stationary: spans may start before the clip), each span "
            "lasting a uniform integer number of frames in [min_frames, max_frames]. "
            "Expected missing fraction 1 - exp(-rate_per_s * E[length] / fps).",
        ),
        "occlusion": _spec(
            {"sigma_px": 0.0, "start_s": None, "length_s": 1.0},
            "All observed joints but the head missing from start_s (default a third of the clip) "
            "for length_s seconds (default 1.0), clipped to the clip, as behind the shrub of the "
            "GPDM paper.",
        ),
        "blackout": _spec(
            {"sigma_px": 0.0, "start_s": None, "length_s": 1.1},
            "Every joint missing from start_s (default a third of the clip) for length_s seconds "
            "(default 1.1, about one gait cycle), clipped to the clip.",
        ),
        "outliers": _spec(
            {"sigma_px": 0.0, "fraction": 0.1, "min_px": 100.0, "max_px": 300.0},
            "Each observed detection is, with probability fraction, replaced by its clean "
            "projection displaced by d (cos a, sin a), a ~ U[0, 2 pi), d ~ U[min_px, max_px].",
        ),
    }
)


# ---------------------------------------------------------------------------- helpers
def _scenario_names() -> str:
    return ", ".join(SCENARIOS)


def _as_float(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise PriortrackError(f"{name}: expected a number, got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise PriortrackError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(out):
        raise PriortrackError(f"{name}: expected a finite number, got {value!r}")
    return out


def _as_int(name: str, value: Any) -> int:
    out = _as_float(name, value)
    if out != int(out):
        raise PriortrackError(f"{name}: expected an integer number of frames, got {value!r}")
    return int(out)


def _validate_params(scenario: str, params: Mapping[str, Any]) -> dict[str, Any]:
    """Merge ``params`` into the scenario defaults and check every value (clip-independent).

    Returns the complete parameter dict (``start_s`` may still be None).
    """
    if scenario not in SCENARIOS:
        raise PriortrackError(f"scenario: unknown scenario {scenario!r}; valid scenarios: {_scenario_names()}")
    defaults = SCENARIOS[scenario].defaults
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        raise PriortrackError(
            f"params: unknown parameter(s) {', '.join(map(repr, unknown))} for scenario {scenario!r}; "
            f"valid parameters: {', '.join(defaults)}"
        )
    merged = dict(defaults)
    merged.update(params)
    out: dict[str, Any] = {}
    for key, value in merged.items():
        if key in ("min_frames", "max_frames"):
            out[key] = _as_int(key, value)
        elif key == "start_s" and value is None:
            out[key] = None
        else:
            out[key] = _as_float(key, value)
    if out["sigma_px"] < 0:
        raise PriortrackError(f"sigma_px: expected >= 0 pixels, got {out['sigma_px']}")
    if "rate_per_s" in out and out["rate_per_s"] < 0:
        raise PriortrackError(f"rate_per_s: expected >= 0 spans per joint per second, got {out['rate_per_s']}")
    if "min_frames" in out:
        if out["min_frames"] < 1:
            raise PriortrackError(f"min_frames: expected an integer >= 1, got {out['min_frames']}")
        if out["max_frames"] < out["min_frames"]:
            raise PriortrackError(
                f"max_frames: expected an integer >= min_frames = {out['min_frames']}, got {out['max_frames']}"
            )
    if "length_s" in out and out["length_s"] <= 0:
        raise PriortrackError(f"length_s: expected a positive duration in seconds, got {out['length_s']}")
    if out.get("start_s") is not None and out["start_s"] < 0:
        raise PriortrackError(f"start_s: expected a non-negative time in seconds (or None), got {out['start_s']}")
    if "fraction" in out and not 0.0 <= out["fraction"] <= 1.0:
        raise PriortrackError(f"fraction: expected a value in [0, 1], got {out['fraction']}")
    if "min_px" in out:
        if out["min_px"] < 0:
            raise PriortrackError(f"min_px: expected >= 0 pixels, got {out['min_px']}")
        if out["max_px"] < out["min_px"]:
            raise PriortrackError(f"max_px: expected >= min_px = {out['min_px']}, got {out['max_px']}")
    return out


def _check_positions(positions: Any) -> np.ndarray:
    if isinstance(positions, torch.Tensor):
        positions = positions.detach().cpu().numpy()
    try:
        arr = np.asarray(positions, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PriortrackError(f"positions: expected an array of shape (T, 15, 3) metres ({exc})") from None
    if arr.ndim != 3 or arr.shape[1:] != (_N_JOINTS, 3) or arr.shape[0] < 1:
        raise PriortrackError(f"positions: expected shape (T, 15, 3) metres in eval15 order, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise PriortrackError(
            f"positions: expected finite values of shape (T, 15, 3), found NaN/inf at frame {bad[0]}, "
            f"joint {bad[1]} ({EVAL15_NAMES[bad[1]]})"
        )
    return arr


def _check_joints(joints: Any) -> tuple[str, ...]:
    if isinstance(joints, str):
        raise PriortrackError(f"joints: expected a sequence of eval15 joint names, got the string {joints!r}")
    try:
        names = tuple(joints)
    except TypeError:
        raise PriortrackError(f"joints: expected a sequence of eval15 joint names, got {joints!r}") from None
    for name in names:
        if name not in EVAL15_NAMES:
            raise PriortrackError(f"joints: unknown joint {name!r}; valid names: {', '.join(EVAL15_NAMES)}")
    if len(set(names)) != len(names):
        raise PriortrackError(f"joints: duplicate joint names in {names}")
    return names


def _check_fps(fps: Any) -> float:
    out = _as_float("fps", fps)
    if out <= 0:
        raise PriortrackError(f"fps: expected a positive frame rate, got {fps!r}")
    return out


def _interval_frames(start_s: float, length_s: float, fps: float, n_frames: int) -> tuple[int, int]:
    """Frames [f0, f1) of an interval: f0 = round(start_s fps), f1 = f0 + max(1, round(length_s fps))."""
    f0 = int(math.floor(start_s * fps + 0.5))
    f1 = f0 + max(1, int(math.floor(length_s * fps + 0.5)))
    c0, c1 = min(f0, n_frames), min(f1, n_frames)
    if (c0, c1) != (f0, f1):
        logger.debug("interval frames [%d, %d) clipped to the clip: [%d, %d)", f0, f1, c0, c1)
    return c0, c1


# ---------------------------------------------------------------------------- Observations
class Observations:
    """A sequence of 2D joint observations in pixels.

    Attributes:
        uv: (T, 15, 2) float64 pixels in eval15 order, NaN where missing (always NaN for
            joints not in ``joints``).
        joints: tuple of observed eval15 joint names.
        scenario: name of the corruption scenario (a key of ``SCENARIOS``, or any label).
        params: dict of the scenario parameters actually used (defaults filled in,
            ``start_s`` resolved to seconds).
        seed: int seed of ``numpy.random.default_rng`` (None if unknown / a Generator was given).
        fps: frames per second.
        camera: the :class:`PinholeCamera` that produced ``uv``.

    Raises:
        PriortrackError: wrong ``uv`` shape, unknown/duplicate joint names, a non-NaN
            entry for a joint not in ``joints``, non-positive ``fps``.
    """

    def __init__(
        self,
        uv: Any,
        joints: Sequence[str],
        scenario: str,
        params: Mapping[str, Any],
        seed: int | None,
        fps: float,
        camera: PinholeCamera,
    ) -> None:
        if isinstance(uv, torch.Tensor):
            uv = uv.detach().cpu().numpy()
        try:
            uv_arr = np.array(uv, dtype=np.float64)  # copy
        except (TypeError, ValueError) as exc:
            raise PriortrackError(f"uv: expected an array of shape (T, 15, 2) pixels ({exc})") from None
        if uv_arr.ndim != 3 or uv_arr.shape[1:] != (_N_JOINTS, 2):
            raise PriortrackError(f"uv: expected shape (T, 15, 2) pixels in eval15 order, got {uv_arr.shape}")
        self.joints = _check_joints(joints)
        unobserved = [j for j, name in enumerate(EVAL15_NAMES) if name not in self.joints]
        if unobserved and not np.all(np.isnan(uv_arr[:, unobserved])):
            raise PriortrackError(
                "uv: entries of joints not in joints must be NaN; found values for "
                f"{[EVAL15_NAMES[j] for j in unobserved if not np.all(np.isnan(uv_arr[:, j]))]}"
            )
        if not isinstance(camera, PinholeCamera):
            raise PriortrackError(f"camera: expected a PinholeCamera, got {type(camera).__name__}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise PriortrackError(f"seed: expected an int or None, got {seed!r}")
        self.uv = uv_arr
        self.scenario = str(scenario)
        self.params = dict(params)
        self.seed = None if seed is None else int(seed)
        self.fps = _check_fps(fps)
        self.camera = camera

    @property
    def missing(self) -> np.ndarray:
        """(T, 15) bool: True where uv[t, j] has a NaN coordinate (unobserved or dropped)."""
        return np.isnan(self.uv).any(axis=-1)

    @property
    def n_frames(self) -> int:
        """Number of frames T."""
        return int(self.uv.shape[0])

    @property
    def joint_indices(self) -> tuple[int, ...]:
        """eval15 indices of ``joints``, in the order of ``joints``."""
        return tuple(EVAL15_NAMES.index(name) for name in self.joints)

    def __repr__(self) -> str:
        return (
            f"Observations(T={self.n_frames}, joints={len(self.joints)}, scenario={self.scenario!r}, "
            f"params={self.params}, seed={self.seed}, fps={self.fps:g}, "
            f"missing={float(self.missing[:, list(self.joint_indices)].mean()) if self.joints else 1.0:.3f})"
        )

    # ------------------------------------------------------------------ storage
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write to ``path`` (npz, written exactly at that path, no pickle).

        Arrays: ``uv`` (T, 15, 2) float64 and ``metadata``, a JSON string with keys
        format_version (= 1), joints, scenario, params, seed, fps, camera (``to_dict``).
        """
        meta = {
            "format_version": FORMAT_VERSION,
            "joints": list(self.joints),
            "scenario": self.scenario,
            "params": self.params,
            "seed": self.seed,
            "fps": self.fps,
            "camera": self.camera.to_dict(),
        }
        try:
            text = json.dumps(meta)
        except TypeError as exc:
            raise PriortrackError(f"params: values must be JSON-serialisable numbers/strings ({exc})") from None
        with open(output_path(path, "observations file"), "wb") as fh:
            np.savez(fh, uv=self.uv, metadata=np.array(text))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "Observations":
        """Read a file written by :meth:`save` (``np.load(allow_pickle=False)``).

        Raises:
            PriortrackError: not an npz file, a missing key (``uv``, ``metadata`` or a
                metadata key), an unsupported ``format_version`` or invalid contents;
                the message names the file and the key.
        """
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}
        except FileNotFoundError:
            raise
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
            raise PriortrackError(f"{path}: not a readable observations npz file ({exc})") from None
        for key in ("uv", "metadata"):
            if key not in arrays:
                raise PriortrackError(f"{path}: missing key {key!r} (expected uv, metadata)")
        try:
            meta = json.loads(str(arrays["metadata"][()]))
        except (json.JSONDecodeError, TypeError, IndexError) as exc:
            raise PriortrackError(f"{path}: key 'metadata' is not a JSON string ({exc})") from None
        if not isinstance(meta, dict):
            raise PriortrackError(f"{path}: key 'metadata' must hold a JSON object")
        for key in _META_KEYS:
            if key not in meta:
                raise PriortrackError(f"{path}: metadata is missing key {key!r} (expected {', '.join(_META_KEYS)})")
        if meta["format_version"] != FORMAT_VERSION:
            raise PriortrackError(
                f"{path}: key 'format_version' is {meta['format_version']!r}, this version reads only "
                f"{FORMAT_VERSION}"
            )
        if not isinstance(meta["params"], dict):
            raise PriortrackError(f"{path}: key 'params' must be a JSON object")
        try:
            camera = PinholeCamera.from_dict(meta["camera"])
            return cls(
                arrays["uv"], meta["joints"], meta["scenario"], meta["params"], meta["seed"], meta["fps"], camera
            )
        except PriortrackError as exc:
            raise PriortrackError(f"{path}: {exc}") from None


# ---------------------------------------------------------------------------- synthesis
def default_camera(positions: Any, margin: float = 0.1) -> PinholeCamera:
    """A side-view camera that keeps the whole motion in a 1000x1000 image (f = 1000 px).

    The camera looks horizontally at the centre c of the motion's bounding box, from eye
    height 1.5 m, along the horizontal direction w perpendicular to the main direction of
    travel of the pelvis (the first principal axis of its x-z track), so a walker crosses
    the image from side to side; a motion that travels less than 0.5 m is seen along -z:

        eye = c + d·w (at y = 1.5 m),  PinholeCamera.look_at(eye, c)

    with d the smallest distance ≥ 5 m (grown by 5 % steps) at which every joint of every
    frame projects inside the image with a ``margin`` fraction of its size free on each side.

    Args:
        positions: (T, 15, 3) metres, world Y-up.
        margin: free border as a fraction of the image size, in [0, 0.45].

    Raises:
        PriortrackError: wrong positions shape / NaN, or a bad margin.
    """
    pos = _check_positions(positions)
    margin = _as_float("margin", margin)
    if not 0.0 <= margin <= 0.45:
        raise PriortrackError(f"margin: expected a fraction in [0, 0.45], got {margin}")
    focal, size, eye_height = 1000.0, 1000, 1.5
    points = pos.reshape(-1, 3)
    c = (points.min(axis=0) + points.max(axis=0)) / 2.0
    track = pos[:, 0, [0, 2]] - pos[:, 0, [0, 2]].mean(axis=0)
    w = np.array([0.0, 0.0, 1.0])
    if np.ptp(track, axis=0).max() >= 0.5:
        travel = np.linalg.svd(track, full_matrices=False)[2][0]       # unit (x, z)
        w = np.array([-travel[1], 0.0, travel[0]])
    low_px, high_px = margin * size, (1.0 - margin) * size
    d = 5.0
    for _ in range(200):
        eye = np.array([c[0] + d * w[0], eye_height, c[2] + d * w[2]])
        cam = PinholeCamera.look_at(eye, c, focal_px=focal, width=size, height=size)
        uv, in_front = cam.project(points)
        if in_front.all() and np.all(uv >= low_px) and np.all(uv <= high_px):
            return cam
        d *= 1.05
    logger.warning("default_camera: could not fit the motion in the image; using d = %.2f m", d)
    return cam


def synthesize(
    positions: Any,
    fps: float,
    camera: PinholeCamera | None,
    scenario: str = "clean",
    seed: int | np.random.Generator = 0,
    joints: Iterable[str] = PAPER_OBSERVED,
    **params: Any,
) -> Observations:
    """Synthetic 2D observations of 3D joint positions.

    Args:
        positions: (T, 15, 3) metres, eval15 order, world Y-up, finite (numpy or torch).
        fps: frames per second (> 0).
        camera: the :class:`PinholeCamera`; None uses :func:`default_camera` (positions).
        scenario: a key of ``SCENARIOS``.
        seed: int for ``numpy.random.default_rng(seed)`` (or a Generator, then
            ``Observations.seed`` is None).
        joints: observed eval15 joint names (default the paper's eight, ``PAPER_OBSERVED``).
        **params: scenario parameters (see ``SCENARIOS[scenario].doc``).

    Returns:
        :class:`Observations` with uv (T, 15, 2): uv_clean + sigma_px N(0, I) on observed
        entries, then the scenario applied; NaN for joints not in ``joints``, for joints
        behind the camera and where the scenario removes them.

    Random draws, in this order, from one Generator: noise (T, 15, 2) standard normal;
    then dropout (per eval15 joint: span count, starts, lengths) or outliers
    (selection (T, 15) uniform, angle, distance).

    Raises:
        PriortrackError: bad positions (naming ``positions`` and (T, 15, 3)), unknown
            scenario or parameter (listing the valid ones), out-of-range values.
    """
    pos = _check_positions(positions)
    fps = _check_fps(fps)
    names = _check_joints(joints)
    full = _validate_params(scenario, params)
    if camera is None:
        camera = default_camera(pos)
    elif not isinstance(camera, PinholeCamera):
        raise PriortrackError(f"camera: expected a PinholeCamera or None, got {type(camera).__name__}")
    if isinstance(seed, np.random.Generator):
        rng, seed_record = seed, None
    else:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise PriortrackError(f"seed: expected a non-negative int or a numpy Generator, got {seed!r}")
        rng, seed_record = np.random.default_rng(int(seed)), int(seed)

    n_frames = pos.shape[0]
    duration = n_frames / fps
    if "start_s" in full and full["start_s"] is None:
        full["start_s"] = duration / 3.0

    uv_clean, in_front = camera.project(pos)
    uv_clean = np.asarray(uv_clean, dtype=np.float64)
    n_behind = int((~in_front).sum())
    if n_behind:
        logger.debug("synthesize: %d joint entries behind the camera set to NaN", n_behind)
    observed = np.zeros(_N_JOINTS, dtype=bool)
    observed[[EVAL15_NAMES.index(n) for n in names]] = True
    uv_clean[:, ~observed] = np.nan

    uv = uv_clean + full["sigma_px"] * rng.standard_normal(uv_clean.shape)

    if scenario == "dropout":
        _apply_dropout(uv, rng, fps, full["rate_per_s"], full["min_frames"], full["max_frames"])
    elif scenario == "occlusion":
        f0, f1 = _interval_frames(full["start_s"], full["length_s"], fps, n_frames)
        keep_head = np.zeros(_N_JOINTS, dtype=bool)
        keep_head[_HEAD] = True
        uv[f0:f1, ~keep_head] = np.nan
    elif scenario == "blackout":
        f0, f1 = _interval_frames(full["start_s"], full["length_s"], fps, n_frames)
        uv[f0:f1] = np.nan
    elif scenario == "outliers":
        _apply_outliers(uv, uv_clean, rng, full["fraction"], full["min_px"], full["max_px"])

    return Observations(uv, names, scenario, full, seed_record, fps, camera)


def _apply_dropout(
    uv: np.ndarray, rng: np.random.Generator, fps: float, rate_per_s: float, min_frames: int, max_frames: int
) -> None:
    """In place: per joint, spans with Poisson(rate_per_s (T + max_frames - 1) / fps) starts.

    Starts are uniform integers in [-(max_frames - 1), T - 1] (so the process is
    stationary over the clip) and lengths uniform integers in [min_frames, max_frames].
    """
    n_frames = uv.shape[0]
    window = n_frames + max_frames - 1
    for j in range(_N_JOINTS):  # 15 joints, a handful of spans each: cheap
        n_spans = int(rng.poisson(rate_per_s * window / fps))
        starts = rng.integers(-(max_frames - 1), n_frames, size=n_spans)
        lengths = rng.integers(min_frames, max_frames + 1, size=n_spans)
        for s, length in zip(starts, lengths):
            uv[max(0, s) : max(0, s + length), j] = np.nan


def _apply_outliers(
    uv: np.ndarray, uv_clean: np.ndarray, rng: np.random.Generator, fraction: float, min_px: float, max_px: float
) -> None:
    """In place: each observed entry with probability ``fraction`` becomes uv_clean + d (cos a, sin a)."""
    shape = uv.shape[:2]
    select = (rng.random(shape) < fraction) & ~np.isnan(uv).any(axis=-1)
    angle = rng.uniform(0.0, 2.0 * np.pi, size=shape)
    dist = rng.uniform(min_px, max_px, size=shape)
    offset = np.stack([np.cos(angle), np.sin(angle)], axis=-1) * dist[..., None]
    uv[select] = uv_clean[select] + offset[select]


def parse_scenario(spec: str) -> tuple[str, dict[str, float]]:
    """Parse a command-line scenario ``NAME`` or ``NAME:key=value,key=value``.

    Values are floats (``start_s=none`` gives None).  Returns ``(name, params)`` with only
    the given parameters, validated like :func:`synthesize` (unknown name or key, bad
    ranges), ready for ``synthesize(..., scenario=name, **params)``.

    Example: ``parse_scenario("noise:sigma_px=2")`` -> ``("noise", {"sigma_px": 2.0})``.

    Raises:
        PriortrackError: malformed spec, unknown scenario or key, duplicate key, bad value.
    """
    if not isinstance(spec, str):
        raise PriortrackError(f"spec: expected a string NAME or NAME:key=value,..., got {spec!r}")
    name, sep, rest = spec.strip().partition(":")
    name = name.strip()
    if name not in SCENARIOS:
        raise PriortrackError(f"spec: unknown scenario {name!r} in {spec!r}; valid scenarios: {_scenario_names()}")
    params: dict[str, Any] = {}
    if sep and rest.strip():
        for item in rest.split(","):
            key, eq, value = item.partition("=")
            key, value = key.strip(), value.strip()
            if not eq or not key or not value:
                raise PriortrackError(f"spec: expected key=value in {spec!r}, got {item!r}")
            if key in params:
                raise PriortrackError(f"spec: duplicate key {key!r} in {spec!r}")
            if key == "start_s" and value.lower() == "none":
                params[key] = None
                continue
            try:
                params[key] = float(value)
            except ValueError:
                raise PriortrackError(f"spec: value of {key!r} must be a number, got {value!r}") from None
    elif sep:
        raise PriortrackError(f"spec: expected key=value pairs after ':' in {spec!r}")
    _validate_params(name, params)
    return name, params
