"""Every task of `optix design`, by name: one line per task below (``BUILT_IN``). Adding a task
is one module that defines its ``TaskPlugin`` (tasks/plugin.py) and one line here, or a
``register`` call (tests/camera_design/test_task_plugin.py adds a toy task so)."""

from __future__ import annotations

from ..errors import InputError
from . import detection, image_quality
from .plugin import TaskPlugin

BUILT_IN: tuple[TaskPlugin, ...] = (
    image_quality.IQ_SOFTWARE,
    image_quality.IQ_HARDWARE,
    image_quality.LOW_LIGHT,
    detection.PLUGIN,
)

_REGISTRY: dict[str, TaskPlugin] = {}


def register(plugin: TaskPlugin) -> TaskPlugin:
    """Make ``plugin`` a task of `optix design`; a name taken already is refused."""
    if plugin.name in _REGISTRY:
        raise InputError(f"a task named {plugin.name!r} is registered already")
    _REGISTRY[plugin.name] = plugin
    return plugin


def unregister(name: str) -> None:
    """Remove a task registered with ``register`` (the built-in ones stay)."""
    if any(p.name == name for p in BUILT_IN):
        raise InputError(f"{name!r} is a built-in task")
    _REGISTRY.pop(name, None)


def plugin(name: str) -> TaskPlugin:
    """The task called ``name``; one error listing the known tasks otherwise."""
    if name not in _REGISTRY:
        raise InputError(f"unknown task {name!r}: known tasks are {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


def plugins() -> tuple[TaskPlugin, ...]:
    """Every registered task, the built-in ones first."""
    return tuple(_REGISTRY.values())


for _p in BUILT_IN:
    register(_p)
