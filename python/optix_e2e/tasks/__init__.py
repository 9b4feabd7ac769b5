"""What the camera is for (paper Sec. 6): the tasks, their losses and their scenes."""

from ..errors import InputError
from .detection import DETECTION, DetectionTask
from .image_quality import TASKS as IMAGE_QUALITY_TASKS
from .image_quality import ImageQualityTask, TaskLoss, task_loss
from .samples import HeldoutSample, SensorFrame, heldout_set, training_batch

#: every task of ``optix design``: the image-quality tasks and detection
TASKS = {**IMAGE_QUALITY_TASKS, DETECTION.name: DETECTION}


def get_task(name: str) -> "ImageQualityTask | DetectionTask":
    if name not in TASKS:
        raise InputError(f"unknown task {name!r}: known tasks are {', '.join(TASKS)}")
    return TASKS[name]


__all__ = [
    "TASKS",
    "ImageQualityTask",
    "DetectionTask",
    "DETECTION",
    "TaskLoss",
    "get_task",
    "task_loss",
    "SensorFrame",
    "training_batch",
    "heldout_set",
    "HeldoutSample",
]
