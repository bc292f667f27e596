"""Motion priors as transition models: Gaussian diffusion, (balanced) GPDM, Lie-algebra mixture."""

from priortrack.priors.base import KINDS, TransitionModel, load_prior
from priortrack.priors.diffusion import Diffusion

__all__ = ["KINDS", "TransitionModel", "load_prior", "Diffusion"]
