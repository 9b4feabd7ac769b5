"""A design run's memory, estimated before it starts: a batch that cannot fit is refused in one
line up front, instead of an allocator's traceback minutes into the run.

The model (bundled/design/memory_model.json, measured by ``python benches/memory_model.py
--write-model``): per task, the peak of a run is ``base + per_pixel x batch x (crop + 2 m) x
(crop_width + 2 m)``, m the camera's margin (the scene a training step renders is the crop and
the PSF's half-window around it). It was fitted to the peak resident memory of smoke runs on the
CPU from 64 x 64 crops of one scene to several times the quick budget's pixels; a task without
its own fit uses the largest per-pixel cost of those measured.
"""

from __future__ import annotations

import json
import os
import resource
from functools import cache
from pathlib import Path

from ..errors import InputError
from .config import DesignConfig

MODEL_FILE = Path(__file__).resolve().parents[1] / "bundled" / "design" / "memory_model.json"


@cache
def memory_model() -> dict:
    return json.loads(MODEL_FILE.read_text())["model"]


def estimate_bytes(cfg: DesignConfig, margin: int) -> float:
    """The modelled peak memory of ``cfg``'s run whose camera cuts ``margin`` pixels a side."""
    model = memory_model()
    fit = model.get(cfg.task) or max(model.values(), key=lambda f: f["bytes_per_pixel"])
    h, w = cfg.crop_hw
    return fit["base_bytes"] + fit["bytes_per_pixel"] * cfg.batch * (h + 2 * margin) * (w + 2 * margin)


def available_bytes(device: str = "cpu") -> tuple[float, str]:
    """(bytes, what they are) the run may use: the machine's available memory, less where the
    process's address-space limit is lower; on a GPU its free memory."""
    if device.startswith("cuda"):
        import torch

        free, _ = torch.cuda.mem_get_info(torch.device(device))
        return float(free), f"free on {device}"
    avail, what = float("inf"), "available"
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail, what = float(line.split()[1]) * 1024, "available on this machine"
    except OSError:
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        try:
            used = float(Path(f"/proc/{os.getpid()}/statm").read_text().split()[0]) * resource.getpagesize()
        except OSError:
            used = 0.0
        if soft - used < avail:
            avail, what = soft - used, "left under this process's address-space limit (ulimit -v)"
    return avail, what


def check_memory(cfg: DesignConfig, margin: int, device: str = "cpu") -> None:
    """One error, before anything is written, where ``cfg``'s modelled peak exceeds what the
    machine has."""
    need = estimate_bytes(cfg, margin)
    have, what = available_bytes(device)
    if need > have:
        h, w = cfg.crop_hw
        raise InputError(
            f"a training step of batch {cfg.batch} at crop {h} x {w} (+ {margin} px margins) needs about "
            f"{need / 2**30:.1f} GiB (camera_design/memory.py), {have / 2**30:.1f} GiB {what}: "
            "lower batch or crop"
        )
