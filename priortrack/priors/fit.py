"""`fit_prior`: one entry point that fits any prior kind from a list of motions."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.priors.base import TransitionModel
from priortrack.priors.diffusion import Diffusion
from priortrack.priors.gpdm import GPDM
from priortrack.priors.lie import LiePrior

FIT_KINDS = ("diffusion-global", "diffusion-local", "gpdm", "bgpdm", "lie")


def fit_prior(kind: str, motions: Sequence[Motion], progress: Callable[[int, float], None] | None = None,
              **options) -> TransitionModel:
    """Fit a prior of ``kind`` (one of FIT_KINDS) to ``motions``.

    ``progress(step, objective)`` is called as an iterative fit proceeds (GPDM and Lie);
    ``options`` go to the kind's ``fit`` (e.g. ``space="directions"`` for a diffusion,
    ``d=3`` for a GPDM, ``max_components=30`` for the Lie prior).
    """
    if kind in ("diffusion-global", "diffusion-local"):
        return Diffusion.fit(motions, local=kind == "diffusion-local", **options)
    if kind in ("gpdm", "bgpdm"):
        return GPDM.fit(motions, balanced=kind == "bgpdm", progress=progress, **options)
    if kind == "lie":
        return LiePrior.fit(motions, progress=progress, **options)
    raise PriortrackError(f"unknown prior kind {kind!r}; kinds: {', '.join(FIT_KINDS)}")
