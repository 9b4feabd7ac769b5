"""What a task brings to `optix design`: one ``TaskPlugin``, registered once (tasks/registry.py).

A plugin names everything about its task in one place: its definition (what the camera is for:
the ISP kind, the exposure, the scene light; the loss and scenes follow from it), its hooks into
the design run (a camera_design.task_hooks.TaskHooks subclass: how to build, train, evaluate and
summarize its cameras), its settings under each budget (over the common budgets of
camera_design/config.py), its further blocks of parameters beside the lens and the ISP, and its
command-line help.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Mapping


@dataclass(frozen=True)
class TaskPlugin:
    #: the task's definition: a frozen dataclass with at least ``name``, ``isp`` ("software" or
    #: "hardware"), ``exposure_factor``, ``gain_factor``, ``level_min``, ``level_max``, ``description``
    definition: Any
    #: its hooks: the TaskHooks subclass, or "module:Class" where it lies above this layer
    #: (imported when a run first asks for it)
    hooks: "str | type"
    #: the line `optix design --help` shows for it
    help: str
    #: the design settings it changes under each budget ("smoke", "quick", "full"): name -> value
    budgets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    #: parameter blocks of Alg. 1 beside the optics and the ISP, each with its own steps_, lr_ and
    #: beta_ settings in DesignConfig (detection: "detector")
    blocks: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.definition.name

    def hooks_class(self) -> type:
        """The TaskHooks subclass (imported from its "module:Class" the first time)."""
        if isinstance(self.hooks, str):
            module, _, cls = self.hooks.partition(":")
            return getattr(importlib.import_module(module), cls)
        return self.hooks
