"""The optics stage f_OPTIC of the camera (paper Eq. 2, Sec. 4.1): lens parameters ->
surrogate PSFs (:class:`DifferentiableOptics`) -> spatially varying render (:mod:`.render`)."""

from .differentiable import DifferentiableOptics
from .render import render, render_exact

__all__ = ["DifferentiableOptics", "render", "render_exact"]
