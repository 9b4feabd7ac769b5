"""Scenes for training and evaluation, all offline: bundled photos, procedural charts, user folders,
labelled street scenes and COCO detection data."""

from .coco import CocoDetection, CocoFormatError, write_street_coco
from .folder import ImageFolder
from .natural import natural_scene, training_photos
from .photos import bundled_photos, fit_size, load_photo, to_image_tensor
from .procedural import chart_patch_boxes, color_chart, dead_leaves, mixed_scene, random_crops, slanted_edge
from .street import CATEGORIES, StreetScene, street_scene

__all__ = [
    "ImageFolder",
    "bundled_photos",
    "load_photo",
    "fit_size",
    "to_image_tensor",
    "dead_leaves",
    "slanted_edge",
    "color_chart",
    "chart_patch_boxes",
    "mixed_scene",
    "random_crops",
    "street_scene",
    "StreetScene",
    "CATEGORIES",
    "CocoDetection",
    "CocoFormatError",
    "write_street_coco",
    "natural_scene",
    "training_photos",
]
