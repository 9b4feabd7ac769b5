"""What the camera is for (paper Sec. 6): the tasks, their losses and their scenes; every task
of `optix design` is a plugin in one registry (tasks/registry.py)."""

from .detection import DETECTION, DetectionTask
from .image_quality import ImageQualityTask, TaskLoss, task_loss
from .plugin import TaskPlugin
from .registry import plugin, plugins, register
from .samples import HeldoutSample, SensorFrame, heldout_set, training_batch


def get_task(name: str) -> "ImageQualityTask | DetectionTask":
    """The definition of the task called ``name`` (its plugin's); one error for an unknown name."""
    return plugin(name).definition


__all__ = [
    "ImageQualityTask",
    "DetectionTask",
    "DETECTION",
    "TaskLoss",
    "TaskPlugin",
    "get_task",
    "plugin",
    "plugins",
    "register",
    "task_loss",
    "SensorFrame",
    "training_batch",
    "heldout_set",
    "HeldoutSample",
]
