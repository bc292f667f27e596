"""Motion priors as transition models: Gaussian diffusion, (balanced) GPDM, Lie-algebra mixture.

Importing this package registers every prior kind, so :func:`load_prior` reads them all.
"""

from priortrack.priors.base import KINDS, TransitionModel, load_prior
from priortrack.priors.diffusion import Diffusion
from priortrack.priors.gpdm import GPDM
from priortrack.priors.lie import LiePrior
from priortrack.priors.fit import FIT_KINDS, fit_prior

__all__ = ["KINDS", "FIT_KINDS", "TransitionModel", "load_prior", "fit_prior", "Diffusion", "GPDM", "LiePrior"]
