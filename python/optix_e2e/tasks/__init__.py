"""What the camera is for (paper Sec. 6): the tasks, their losses and their scenes."""

from .image_quality import TASKS, ImageQualityTask, TaskLoss, get_task, task_loss
from .scenes import HeldoutSample, SensorFrame, heldout_set, training_batch

__all__ = ["TASKS", "ImageQualityTask", "TaskLoss", "get_task", "task_loss", "SensorFrame", "training_batch",
           "heldout_set", "HeldoutSample"]
