"""Motion priors as transition models: Gaussian diffusion, (balanced) GPDM, Lie-algebra mixture.

The kinds are listed once, in :mod:`priortrack.priors.registry`; :func:`load_prior` reads any of them.
The names below are imported on first use, so that the registry (and the command line's help)
loads without torch.
"""

import importlib

_NAMES = {
    "TransitionModel": "priortrack.priors.base", "load_prior": "priortrack.priors.base",
    "Diffusion": "priortrack.priors.diffusion", "GPDM": "priortrack.priors.gpdm", "LiePrior": "priortrack.priors.lie",
    "PRIOR_KINDS": "priortrack.priors.registry", "fit_prior": "priortrack.priors.registry",
    "prior_kind": "priortrack.priors.registry",
}
__all__ = list(_NAMES)


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(importlib.import_module(_NAMES[name]), name)
    raise AttributeError(f"module 'priortrack.priors' has no attribute {name!r}")
