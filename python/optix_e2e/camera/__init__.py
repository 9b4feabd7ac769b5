"""The camera as one differentiable pipeline (paper Fig. 2, Eqs. 10-12): optics -> sensor ->
ISP, each stage with its parameter block for the end-to-end optimizer (camera_design/)."""

from .pipeline import Camera
from .stages import FixedOptics, HardwareISPStage, PerfectOptics, SensorStage, SoftwareISPStage, calibrated_preset

__all__ = [
    "Camera",
    "FixedOptics",
    "SensorStage",
    "SoftwareISPStage",
    "HardwareISPStage",
    "PerfectOptics",
    "calibrated_preset",
]
