"""Speed against accuracy: converged reference PSFs, error metrics, the sweep over methods
and settings behind ``optix bench accuracy``, and its charts (docs/accuracy.md)."""

from .psf_errors import ee_radius, rel_l1, rel_l2, render_error, scene_chart
from .reference import Reference, converged_reference

__all__ = ["Reference", "converged_reference", "ee_radius", "rel_l1", "rel_l2", "render_error", "scene_chart"]
