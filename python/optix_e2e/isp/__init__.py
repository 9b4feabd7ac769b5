"""ISP stage (paper Secs. 3.4, 3.5, 4.2): a reference "hardware" ISP (numpy, not
differentiable), its learned differentiable proxy, and a software ISP (UNet)."""

from . import params
from .demosaick import BilinearDemosaick, bilinear_demosaick
from .proxy import ISPProxy
from .reference import ReferenceISP
from .software import SoftwareISP
from .unet import UNet

__all__ = ["params", "ReferenceISP", "ISPProxy", "SoftwareISP", "UNet", "BilinearDemosaick", "bilinear_demosaick"]
