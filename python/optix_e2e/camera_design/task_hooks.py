"""What a task adds to the design run (run.py, the skeleton: claim the folder, build, train the
end-to-end camera and the nominal baseline with the same budget, checkpoint and resume, compute
both lenses' exact PSFs, evaluate on held-out data, write the outputs). A task is a plugin
(tasks/plugin.py, registered in tasks/registry.py) whose hooks are a ``TaskHooks`` subclass that
builds its camera and loss, evaluates and summarizes. The image-quality tasks (iq-software,
iq-hardware, low-light) share ``image_quality.ImageQualityHooks``; detection has
``detection.DetectionHooks``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from .. import parallel
from ..camera import FixedOptics
from ..errors import InputError
from ..surrogate.checkpoint import OpticsSurrogate
from ..tasks import SensorFrame, get_task
from .config import DesignConfig


@dataclass
class RunState:
    """A design run after its trainings, as the hooks see it (run.py fills it in, in this order).

    ``cams``: the cameras by who: "nominal" and "end_to_end", and the task's further baselines
    ("nominal_untuned", "ideal_lens"). ``optics``: for "nominal" and "end_to_end", the optics each
    is evaluated under: "exact", the engine's (PSFs [K, 3, S, S], vignetting [K, 3], field heights
    [K] in mm) of its lens, and "surrogate", the network's (None where no network learned the
    space). ``f_numbers``: each lens's working f-number where the task sets its photons by it
    (else None). ``exact``: the engine's output for both lenses (surrogate.ground_truth.exact_optics).
    Then ``evaluation`` (TaskHooks.evaluate's) and ``reports`` (each lens's report,
    lens_design.report.write_report)."""

    cfg: DesignConfig
    out: Path
    frame: SensorFrame
    sur: OpticsSurrogate
    cams: dict[str, Any]
    optics: dict[str, dict[str, Any]]
    f_numbers: dict[str, "float | None"]
    exact: dict
    progress: bool = False
    evaluation: Any = None
    reports: "dict[str, dict] | None" = None


class TaskHooks:
    """The hooks of one task, in the order the run calls them. ``cfg`` is the run's settings,
    ``task`` the task's definition (tasks.get_task), ``device`` where the cameras run (--device)."""

    #: the loss terms the task reports besides the total (history.csv, TensorBoard)
    loss_parts: tuple[str, ...] = ()
    #: exact PSFs of a design the engine's FFT refuses: None (an error) or "huygens"
    exact_fallback: str | None = None
    #: the user's training images (``--images``: scenes.ImageFolder), where the task takes them
    folder = None
    corpus = None  # a scenes.corpus.PhotoCorpus of training photographs (the photos setting)

    def __init__(self, cfg: DesignConfig, device: "torch.device | str" = "cpu"):
        self.cfg = cfg
        self.task = get_task(cfg.task)
        self.device = torch.device(device)

    def check(self, sur: OpticsSurrogate, ranks: parallel.Ranks) -> None:
        """Refuse settings the task cannot run with, before the run folder is claimed."""

    def describe(self) -> str:
        """The end-to-end training's line in the log."""
        c = self.cfg
        return f"end-to-end training: {c.task}, {c.optimizer}, {c.total_steps} steps"

    def build_camera(
        self,
        sur: OpticsSurrogate,
        frame: SensorFrame,
        *,
        fixed_optics: FixedOptics | None = None,
        trained: bool = False,
    ):
        """The camera at its initialization; ``fixed_optics`` for the nominal baseline; ``trained``:
        the end-to-end camera the run trains (a hybrid run's optics refine their own surrogate)."""
        raise NotImplementedError

    def monitor(self, camera, writer, log):
        """What checks the optics model along the end-to-end training (or None)."""
        return None

    def loss_at(self, camera, frame: SensorFrame, ranks: parallel.Ranks):
        """``loss_at(t, generator) -> (loss, parts)``: step t's loss (None: the default of
        training.train, the image-quality loss)."""
        return None

    def nominal_optics(self, camera, sur: OpticsSurrogate, nominal_values, surrogate_psfs, frame) -> FixedOptics:
        """The optics the nominal baseline trains through (the nominal lens, fixed)."""
        raise NotImplementedError

    def ideal_optics(self, sur: OpticsSurrogate, nominal_values, frame) -> FixedOptics | None:
        """The ideal lens the baseline's processing is also fine-tuned behind, on the same budget
        (results.json ``ideal_lens``: the ceiling of what a lens could add); None: the task has none."""
        return None

    def untuned_camera(self, sur: OpticsSurrogate, frame: SensorFrame, nominal_optics: FixedOptics):
        """The nominal lens behind the processing as it is before any fine-tuning (results.json
        ``nominal_untuned``); None: the task has no such baseline."""
        return None

    def f_number(self, values) -> float | None:
        """The working f-number of a design where the task sets the photons by it (Eq. 3)."""
        return None

    def evaluate(self, run: RunState):
        """Both cameras on the held-out data under each optics ("exact", "surrogate"), and the
        task's further baselines in ``run.cams`` (``ideal_optics``, ``untuned_camera``); returns
        (the evaluation, the seconds of evaluations reused from an earlier call)."""
        raise NotImplementedError

    def test_split(self, run: RunState, corpus, baseline: str):
        """Every camera on the untouched test split (``corpus``: a scenes.corpus.PhotoCorpus of
        role test; docs/test-split.md), the end-to-end camera paired against each other camera;
        ``baseline``: the headline baseline the held-out set chose (results.json ``test_split``)."""
        raise InputError(f"task {self.cfg.task}: the test split of photographs is for the image-quality tasks")

    def panels(self, run: RunState, path: Path) -> None:
        """The image panels (panels.png)."""
        raise NotImplementedError

    def summarize(self, run: RunState) -> dict:
        """The task's figures for results.json: ``nominal``, ``end_to_end``, ``paired``, ..."""
        raise NotImplementedError

    def held_out(self, run: RunState) -> dict:
        """What the held-out set was (results.json ``held_out``)."""
        raise NotImplementedError

    def extra(self, run: RunState, monitor, e2e: dict) -> dict:
        """Further results.json entries (the optics model, the ISP's hyperparameters)."""
        return {}

    def write_tables(self, run: RunState) -> None:
        """metrics.csv: the per-image (per-scene) figures."""
        raise NotImplementedError

    @staticmethod
    def summary_lines(results: dict) -> list[str]:
        """What ``optix design`` prints about the results (from results.json alone)."""
        raise NotImplementedError
