"""The torch device a command runs on: one reading of ``--device`` for every command (issue 36).

``auto`` is CUDA when torch sees a GPU, else the CPU; ``cpu``; ``cuda`` (the first GPU, or under
torchrun the process's own, ``local_rank``); ``cuda:K``. A GPU that is not there is an error
naming the option and what the machine has, never a quiet fall-back to the CPU.

What repeats where: on the CPU a seeded run gives the same figures whatever the thread count.
On CUDA the seeded draws (batches, lens starts, sensor noise) are made on the CPU and moved, so
they are the CPU's; the arithmetic is not (other kernels, TF32, non-deterministic reductions),
so a CUDA run's figures differ from the CPU's in their last digits and may differ from one CUDA
run to the next.
"""

from __future__ import annotations

import re

import torch

from .errors import InputError

FORMS = "auto, cpu, cuda or cuda:K (K a GPU index)"
_CUDA = re.compile(r"cuda(?::(\d+))?")


def resolve_device(spec: str, *, local_rank: int = 0, option: str = "--device") -> torch.device:
    """The device ``spec`` names (module doc). ``option``: how the user gave it, for the error
    (``--device``, or a config file's setting)."""
    if not isinstance(spec, str):
        raise InputError(f"{option} must be {FORMS}, got {spec!r}")
    if spec == "auto":
        return torch.device("cuda", local_rank) if torch.cuda.is_available() else torch.device("cpu")
    if spec == "cpu":
        return torch.device("cpu")
    m = _CUDA.fullmatch(spec)
    if m is None:
        raise InputError(f"{option} {spec!r}: expected {FORMS}")
    if not torch.cuda.is_available():
        raise InputError(f"{option} {spec}: this machine has no CUDA device torch can use; give {option} cpu or auto")
    index = int(m.group(1)) if m.group(1) is not None else local_rank
    n = torch.cuda.device_count()
    if index >= n:
        have = "cuda:0" if n == 1 else f"cuda:0 .. cuda:{n - 1}"
        raise InputError(f"{option} {spec}: this machine has {n} CUDA device{'s' * (n != 1)} ({have})")
    return torch.device("cuda", index)
