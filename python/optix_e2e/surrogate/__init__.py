"""The optics surrogate (paper Sec. 4.1): lens parameters + field -> RGB PSF and vignetting."""

from .checkpoint import OpticsSurrogate, SurrogateFileError, SurrogateRangeError
from .loss import LossWeights, OpticsLoss, optics_loss, optics_loss_terms
from .model import SurrogateConfig, SurrogateNet

__all__ = [
    "OpticsSurrogate",
    "SurrogateRangeError",
    "SurrogateFileError",
    "SurrogateConfig",
    "SurrogateNet",
    "LossWeights",
    "OpticsLoss",
    "optics_loss",
    "optics_loss_terms",
]
