"""The one registry of prior kinds: name → class, fit arguments, option schema, capabilities.

``fit``, presets, the prior cache, ``load_prior`` and the command line all read this table;
adding a prior touches this file and the prior's own module. The table itself imports nothing
heavy (classes are imported on first use), so the command line can list kinds without torch.

Capabilities say what a filter may ask of a kind's transition model
(:mod:`priortrack.models.protocols`):

- ``"gaussian"``: one Gaussian transition, a mean step and ``transition_covariance(x)``
  (the unscented filter runs it; the Lie mixture's conditional moment-matched to one Gaussian);
- ``"mixture"``: that transition as the mixture of Gaussian steps it is, ``step_weights(x)`` and
  ``step_components(x)`` (the Gaussian-sum unscented filter runs one member per component);
- ``"latent"``: a GPDM latent space with its GP maps (the sliding-window MAP tracker runs it).
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from priortrack.errors import PriortrackError

#: Fit parameters the registry or the caller sets, never a preset's ``options``.
_NOT_OPTIONS = ("cls", "motions", "progress", "fps")


@dataclass(frozen=True)
class PriorKind:
    """One kind of prior.

    Attributes:
        name: the kind's name ("diffusion-local", …), as stored in prior files.
        module, cls: where its :class:`~priortrack.priors.base.TransitionModel` class lives.
        fixed: arguments of the class's ``fit`` that the kind fixes (``local=True``).
        capabilities: what filters may ask of it (module docstring).
        summary: one line for listings.
    """

    name: str
    module: str
    cls: str
    fixed: dict[str, Any] = field(default_factory=dict)
    capabilities: frozenset[str] = frozenset()
    summary: str = ""

    def prior_class(self) -> type:
        """The TransitionModel class (imported on first use)."""
        return getattr(importlib.import_module(self.module), self.cls)

    def options(self) -> dict[str, Any]:
        """The option schema: keyword → default of the class's ``fit``, less what the kind fixes
        and what the caller sets (motions, fps, progress)."""
        signature = inspect.signature(self.prior_class().fit)
        return {name: p.default for name, p in signature.parameters.items()
                if name not in (*_NOT_OPTIONS, *self.fixed)
                and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}

    def fit(self, motions: Sequence, progress: Callable[[int, float], None] | None = None, **options):
        """Fit this kind to ``motions`` with ``options`` (checked against :meth:`options`; ``fps``,
        the prior's frame rate, is taken too)."""
        check_options(self.name, {k: v for k, v in options.items() if k != "fps"}, self.options(), "options")
        fit = self.prior_class().fit
        extra = {"progress": progress} if "progress" in inspect.signature(fit).parameters else {}
        return fit(motions, **self.fixed, **extra, **options)


PRIOR_KINDS: dict[str, PriorKind] = {kind.name: kind for kind in (
    PriorKind("diffusion-global", "priortrack.priors.diffusion", "Diffusion", {"local": False},
              frozenset({"gaussian"}), "x_t = x_{t-1} ⊞ ε, one σ for every joint"),
    PriorKind("diffusion-local", "priortrack.priors.diffusion", "Diffusion", {"local": True},
              frozenset({"gaussian"}), "x_t = x_{t-1} ⊞ ε, one σ per joint"),
    PriorKind("gpdm", "priortrack.priors.gpdm", "GPDM", {"balanced": False},
              frozenset({"gaussian", "latent"}), "Gaussian process dynamical model (Wang et al. 2008)"),
    PriorKind("bgpdm", "priortrack.priors.gpdm", "GPDM", {"balanced": True},
              frozenset({"gaussian", "latent"}), "balanced GPDM (Urtasun et al. 2006)"),
    PriorKind("lie", "priortrack.priors.lie", "LiePrior", {},
              frozenset({"gaussian", "mixture"}), "geodesic mixture over bone directions and velocities (Simo-Serra et al. 2015)"),
)}


def prior_kind(name: str) -> PriorKind:
    """The registered kind ``name``; a PriortrackError listing the kinds otherwise."""
    try:
        return PRIOR_KINDS[name]
    except (KeyError, TypeError):
        raise PriortrackError(f"unknown prior kind {name!r}; kinds: {', '.join(PRIOR_KINDS)}") from None


def kinds_with(capability: str) -> tuple[str, ...]:
    """The kinds that have ``capability``."""
    return tuple(name for name, kind in PRIOR_KINDS.items() if capability in kind.capabilities)


def fit_prior(kind: str, motions: Sequence, progress: Callable[[int, float], None] | None = None, **options):
    """Fit a prior of ``kind`` to ``motions``.

    ``progress(step, objective)`` is called as an iterative fit proceeds (GPDM and Lie);
    ``options`` go to the kind's ``fit`` (e.g. ``space="directions"`` for a diffusion,
    ``d=3`` for a GPDM, ``max_components=30`` for the Lie prior, ``fps`` for any).
    """
    return prior_kind(kind).fit(motions, progress=progress, **options)


def check_options(kind: str, options: dict, schema: dict[str, Any], where: str) -> None:
    """Raise a PriortrackError naming any key of ``options`` not in ``schema``, with the valid keys."""
    unknown = sorted(set(options) - set(schema))
    if unknown:
        raise PriortrackError(f"{where} ({kind}): unknown key{'s' if len(unknown) > 1 else ''} "
                              f"{', '.join(map(repr, unknown))}; valid keys: {', '.join(sorted(schema))}")
