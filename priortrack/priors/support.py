"""A prior's support: is a motion one the prior knows? (``priortrack eval fit-check``)

**The figure.** Per frame t ≥ 1 of a motion at the prior's rate, the log-density the prior gives it,

    ℓ_t = ln p(x_t | x_{t−1})                                 (every prior's ``log_prob``),
    ℓ_t = ln p(x_t | x_{t−1}) + ln p(y_t | x_t)               (a GPDM: its latents x are fitted to the
                                                               poses y, eq. 18, so the dynamics alone
                                                               would call any pose familiar),

with x the encoded states (:meth:`encode`) and, for a GPDM, ln p(y | x) = −(eq. 18's energy).

**The reference.** The same figure on frames the prior was *not* fitted on, but which are of its
kind: the preset's training motions split into two folds within each person (a person's motions
alternate, a single motion is halved; with fewer than four motions, the halves of each), a prior of
the same kind and options fitted on each fold, and
ℓ_t taken on the other fold. (Frames the prior
was fitted on would set the bar too high: the Lie prior scores them 30 nats a frame above a held-out
walk.) The reference is cached beside the priors, keyed by the preset's cache key.

**The verdict.** The share of the motion's frames below the reference's 1st percentile (a frame of
the prior's own kind falls there 1 % of the time): below ``IN_SUPPORT`` "in support", above
``OUTSIDE`` "outside", between them "partly". A diffusion prior models step sizes, not poses: a
slow motion of any kind is in its support. Measured shares (pf-lie / pf-gpdm presets): held-out
walks 07_10 0.08 / 0.25, 35_29 0.00 / 0.36, 07_11 (slower) 0.50 / 0.69; balance 49_18, dance 131_04,
martial arts 135_06, jump 13_39, kick 11_01, playground 01_01: 0.96–1.00 / 0.89–1.00. The thresholds
sit in that gap; a walk unlike the training walks lands in "partly", as 07_11 does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from priortrack.data.bundled import person_of
from priortrack.data.motion import Motion
from priortrack.data.npz import read_npz
from priortrack.errors import PriortrackError
from priortrack.priors.base import prepare_motions
from priortrack.priors.registry import PRIOR_KINDS, fit_prior


#: Share of frames below the reference's 1st percentile: under IN_SUPPORT "in support", over OUTSIDE
#: "outside". Set on the bundled clips (module docstring's table), not on one file.
IN_SUPPORT, OUTSIDE = 0.5, 0.85
#: The most a cached reference may hold (10⁶ frames).
REFERENCE_BYTES = 8 * 10**6
#: Transitions :func:`frame_log_density` scores at a time.
FRAMES_AT_ONCE = 1000
#: Training motions from which the reference's folds are whole motions (fewer: halves of each).
MIN_MOTION_FOLDS = 4
#: The reference's own version, part of its cache name: a change in how it is made is not read from an old file.
REFERENCE_VERSION = 2
#: Percentiles of the reference reported with a verdict.
PERCENTILES = (1, 5, 25, 50, 75, 95, 99)


def frame_log_density(prior, motion: Motion) -> np.ndarray:
    """(T − 1,) ℓ_t of ``motion``'s frames 1 … T − 1 at the prior's rate (module docstring), float64, the
    transitions scored FRAMES_AT_ONCE at a time (a mixture's per-component terms of a ten-minute run's 18,000
    at once held hundreds of MB)."""
    motion = prepare_motions([motion], prior.fps)[0]
    x = prior.encode(motion).detach().to(torch.float64)        # (a GPDM's encoding optimises: not under no_grad)
    latent = "latent" in PRIOR_KINDS[prior.kind].capabilities
    y = prior.space.angles.encode(motion).to(torch.float64) if latent else None
    pieces = []
    with torch.no_grad():
        for start in range(1, len(x), FRAMES_AT_ONCE):
            t = slice(start, min(start + FRAMES_AT_ONCE, len(x)))
            ell = prior.log_prob(x[t], x[t.start - 1:t.stop - 1]).to(torch.float64)
            pieces.append((ell - prior.reconstruction_energy(x[t], y[t]) if latent else ell).cpu().numpy())
    return np.concatenate(pieces) if pieces else np.zeros(0)


def reference(preset, cache: Path | None = None) -> np.ndarray:
    """ℓ_t on held-out frames of the preset's training data (module docstring): two-fold cross-fits (with
    the preset's defensive mixture, if it has one: the density it tracks with), cached as
    ``support<version>-<kind>-<key>[-defensive<ε>].npz`` in the prior cache, verified by its digest as the priors are."""
    from priortrack.priors.cache import read_cached, write_cached

    path = reference_path(preset, cache)
    stored = read_cached(path, lambda p: read_npz(p, REFERENCE_BYTES, "support reference")["values"],
                         "support reference")
    if stored is not None:
        return stored
    values = []
    for fit_on, held_out in _folds(list(preset.training_motions)):
        fitted = fit_prior(preset.prior_kind, fit_on, fps=preset.fps, **preset.prior_options)
        fitted = fitted if preset.annealing == 1.0 else fitted.annealed(preset.annealing)
        if preset.defensive:                    # the density the preset tracks with: its defensive mixture
            from priortrack.priors.defensive import DEFENSIVE_SPACES
            from priortrack.priors.defensive import DefensiveMixture

            fallback = fit_prior("diffusion-local", fit_on, fps=preset.fps,
                                 space=DEFENSIVE_SPACES[type(fitted.space).__name__])
            fitted = DefensiveMixture(fitted, fallback, preset.defensive)
        values += [frame_log_density(fitted, m) for m in held_out]
    values = np.concatenate(values)
    write_cached(path, lambda p: np.savez(p, values=values), "support reference")
    return values


def reference_path(preset, cache: Path | None = None) -> Path:
    """Where the prior cache keeps the preset's :func:`reference` (a preset naming a prior file has none: refused)."""
    from priortrack.priors.cache import cache_dir

    if preset.prior_file is not None:
        raise PriortrackError(f"preset {preset.name!r} names a prior file: its training motions are not known, so "
                              f"give reference motions of its kind (--reference)")
    mixed = f"-defensive{preset.defensive:g}" if preset.defensive else ""
    return (cache_dir() if cache is None else Path(cache)) / \
        f"support{REFERENCE_VERSION}-{preset.prior_kind}-{preset.cache_key}{mixed}.npz"


def _folds(motions: list[Motion]) -> list[tuple[list[Motion], list[Motion]]]:
    """Two (fit on, held out) splits within each person: a person's motions alternate between the folds,
    and a person with one motion gives each fold a half of it; with fewer than MIN_MOTION_FOLDS motions
    in all, every motion is halved. Every held-out frame is then of a person the other fold's prior has
    seen: the reference is of the prior's own kind. (Alternate motions regardless of person, with five
    walking people, left 05's only walk out of one fold's training, and its frames, another person's
    gait, set the 1st percentile so low that a balance and a dance came out "partly" in a walking prior.)"""
    if len(motions) < MIN_MOTION_FOLDS:
        return _swapped([m[:len(m) // 2] for m in motions], [m[len(m) // 2:] for m in motions])
    people: dict[str, list[Motion]] = {}
    for m in motions:
        people.setdefault(person_of(m.subject or ""), []).append(m)
    folds: tuple[list[Motion], list[Motion]] = ([], [])
    for own in people.values():
        if len(own) == 1:
            folds[0].append(own[0][:len(own[0]) // 2])
            folds[1].append(own[0][len(own[0]) // 2:])
        else:
            for i, m in enumerate(own):
                folds[i % 2].append(m)
    return _swapped(*folds)


def _swapped(a: list[Motion], b: list[Motion]) -> list[tuple[list[Motion], list[Motion]]]:
    return [(a, b), (b, a)]


def verdict_rule() -> str:
    """The verdicts' thresholds in words, printed beside a share so that a reader sees why it got its verdict."""
    return (f"'in support' under {100 * IN_SUPPORT:.0f}% of the frames below it, 'outside' over {100 * OUTSIDE:.0f}%, "
            f"'partly' between")


def verdict(ell: np.ndarray, reference_values: np.ndarray) -> dict:
    """The fit-check result of frame log-densities ``ell`` against ``reference_values`` (module docstring):
    {"verdict", "below_p1_fraction", "median_log_density", "median_percentile", "reference_percentiles",
    "frame_percentiles" (each frame's percentile within the reference)}."""
    ell, reference_values = np.asarray(ell, dtype=float), np.sort(np.asarray(reference_values, dtype=float))
    if not len(ell) or not len(reference_values):
        raise PriortrackError("fit-check needs at least two frames of the motion and of the reference")
    if not np.isfinite(ell).all():
        ell = np.where(np.isfinite(ell), ell, -np.inf)             # a density of 0: below everything
    percentile = 100 * np.searchsorted(reference_values, ell, side="right") / len(reference_values)
    below = float(np.mean(ell < np.percentile(reference_values, 1)))
    word = "in support" if below < IN_SUPPORT else "outside" if below > OUTSIDE else "partly"
    return {"verdict": word, "below_p1_fraction": below, "median_log_density": float(np.median(ell)),
            "median_percentile": float(np.median(percentile)),
            "reference_percentiles": {str(p): float(np.percentile(reference_values, p)) for p in PERCENTILES},
            "frame_percentiles": percentile.tolist()}
