"""Data-parallel training over processes started by ``torchrun`` (docs/distributed.md).

``torchrun --nproc_per_node N -m optix_e2e surrogate train ...`` (or ``... design ...``)
starts N copies of the command; each reads its rank from the environment torchrun sets
(RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR, MASTER_PORT) and :func:`setup` joins them in
one process group: gloo on CPU, NCCL on CUDA (one GPU per process, ``cuda:LOCAL_RANK``).
Without those variables everything here is the single-process no-op, so the same code
runs with or without torchrun.

Every rank computes its part of each global batch; gradients are averaged over the ranks
before the optimizer step (by DistributedDataParallel for the surrogate, by
:func:`average_gradients` where the optimizer switches parameter blocks on and off);
rank 0 alone writes checkpoints, logs and results.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from .device import resolve_device
from .errors import InputError, RunError

MAX_THREADS = 1024  # torch aborts with a segmentation fault when asked for tens of thousands


def set_threads(n: int) -> None:
    """torch's CPU threads: ``n`` in [1, MAX_THREADS], or 0 for torch's default (unchanged)."""
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= MAX_THREADS:
        raise InputError(f"threads must be an integer from 0 (torch's default) to {MAX_THREADS}, got {n!r}")
    if n:
        torch.set_num_threads(n)


class TrainingDiverged(RunError):
    """A training loss or the weights left the finite numbers; the last good checkpoint is kept."""


def stop_if_diverged(
    step: int, kept: "os.PathLike | str | None", hint: str = "lower the learning rate", **values
) -> None:
    """Raise :class:`TrainingDiverged` naming ``step`` and the first non-finite entry of
    ``values`` (floats, tensors or modules: a module counts by its weights). Call it before a
    checkpoint is written, so a diverged run never overwrites the last good one (``kept``)."""
    for name, v in values.items():
        if isinstance(v, torch.nn.Module):
            bad = next(
                (n for n, p in v.state_dict().items() if p.is_floating_point() and not torch.isfinite(p).all()), None
            )
            if bad is None:
                continue
            what = f"the weights ({bad}) are not finite"
        else:
            t = torch.as_tensor(v.detach() if isinstance(v, torch.Tensor) else v)
            if bool(torch.isfinite(t).all()):
                continue
            what = f"the {name} is {t.flatten()[~torch.isfinite(t.flatten())][0].item()}"
        keep = f"; the last good checkpoint ({kept}) is kept" if kept is not None and os.path.exists(kept) else ""
        raise TrainingDiverged(f"training diverged at step {step}: {what}{keep}; {hint}")


def check_finite_weights(state: dict, path: "os.PathLike | str") -> None:
    """A saved state dict ``state`` whose floating tensors must be finite (resuming from NaN
    weights would overwrite a good checkpoint with garbage): one error naming the file and key."""
    for k, v in state.items():
        if isinstance(v, torch.Tensor) and v.is_floating_point() and not bool(torch.isfinite(v).all()):
            raise InputError(f"{path}: the weights are not finite ({k}); this state came from a diverged run")


@dataclass(frozen=True)
class Ranks:
    """This process's place in the group: rank, world size, local rank, its torch device."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")

    @property
    def is_main(self) -> bool:
        """Rank 0: the one process that writes files and logs."""
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world > 1


def _env_int(name: str, default: int) -> int:
    v = os.environ.get(name)
    if v is None:
        return default
    try:
        return int(v)
    except ValueError:
        raise InputError(f"environment variable {name}={v!r} is not an integer (set by torchrun)") from None


def pick_device(name: str, local_rank: int = 0) -> torch.device:
    """``auto``: CUDA when present (under torchrun, the process's own GPU), else CPU
    (device.resolve_device: a GPU that is not there is an error)."""
    return resolve_device(name, local_rank=local_rank)


def setup(device: str = "auto") -> Ranks:
    """Join torchrun's process group (once; later calls return the same ranks) and pick the
    device. A single process (no WORLD_SIZE, or 1) gets ``Ranks(device=...)``."""
    world = _env_int("WORLD_SIZE", 1)
    rank, local = _env_int("RANK", 0), _env_int("LOCAL_RANK", 0)
    if world > 1 and device.startswith("cuda:"):
        raise InputError(
            f"--device {device}: under torchrun each process takes its own GPU (cuda:LOCAL_RANK); "
            f"give --device cuda or auto"
        )
    dev = pick_device(device, local)
    if world <= 1:
        return Ranks(device=dev)
    if not 0 <= rank < world:
        raise InputError(f"RANK={rank} is outside WORLD_SIZE={world}")
    if not dist.is_initialized():
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        dist.init_process_group(backend="nccl" if dev.type == "cuda" else "gloo")
    return Ranks(rank, world, local, dev)


def teardown() -> None:
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def barrier(ranks: Ranks) -> None:
    if ranks.distributed:
        dist.barrier()


def all_sum(x: torch.Tensor, ranks: Ranks) -> torch.Tensor:
    """The sum over ranks of ``x`` (a copy; ``x`` itself where single-process)."""
    if not ranks.distributed:
        return x
    y = x.detach().clone().to(ranks.device)
    dist.all_reduce(y, op=dist.ReduceOp.SUM)
    return y.to(x.device)


def broadcast_value(x: float, ranks: Ranks) -> float:
    """Rank 0's value of a number (a clock reading every rank must agree on)."""
    if not ranks.distributed:
        return x
    t = torch.tensor([x], dtype=torch.float64, device=ranks.device)
    dist.broadcast(t, 0)
    return float(t.item())


def broadcast_params(params, ranks: Ranks) -> None:
    """Copy rank 0's parameter values to every rank (in place)."""
    if not ranks.distributed:
        return
    with torch.no_grad():
        for p in params:
            buf = p.data.to(ranks.device)
            dist.broadcast(buf, 0)
            p.data.copy_(buf.to(p.device))


def average_gradients(params, ranks: Ranks, extra: torch.Tensor | None = None) -> torch.Tensor | None:
    """Average the gradients of ``params`` over the ranks in one all-reduce, what
    DistributedDataParallel does after backward (every rank must pass the same list). A
    parameter without a gradient on some ranks counts as zeros there; one without a gradient
    on every rank keeps none (the optimizer skips it, as it would in one process). ``extra``
    (e.g. the loss) rides along and comes back averaged."""
    if not ranks.distributed:
        return extra
    params = [p for p in params if p.requires_grad]
    parts = [torch.tensor([float(p.grad is not None) for p in params])]  # who has a gradient
    parts += [(p.grad if p.grad is not None else torch.zeros_like(p)).reshape(-1) for p in params]
    if extra is not None:
        parts.append(extra.detach().reshape(-1))
    dtype = torch.float64 if any(p.dtype == torch.float64 for p in params) else torch.float32
    buf = torch.cat([t.to(ranks.device, dtype) for t in parts])
    dist.all_reduce(buf, op=dist.ReduceOp.SUM)
    has = (buf[: len(params)] > 0).tolist()
    buf /= ranks.world
    i = len(params)
    for p, h in zip(params, has):
        if h:
            g = buf[i : i + p.numel()].view_as(p).to(p.device, p.dtype)
            if p.grad is None:
                p.grad = g.clone()
            else:
                p.grad.copy_(g)
        i += p.numel()
    return None if extra is None else buf[i:].view_as(extra).to(extra.device, extra.dtype)


def average_step(ranks: Ranks, params, task: torch.Tensor, info: dict) -> tuple[torch.Tensor, dict]:
    """An optimizer's ``reduce`` (camera_design/alg1.py): average the gradients of ``params``, the
    task loss and the info's numbers over the ranks, in one all-reduce."""
    if not ranks.distributed:
        return task, info
    keys = [k for k, v in info.items() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    extra = torch.tensor([float(task.detach()), *(float(info[k]) for k in keys)], dtype=torch.float64)
    avg = average_gradients(params, ranks, extra)
    return avg[0].to(task.dtype), {**info, **{k: float(v) for k, v in zip(keys, avg[1:])}}


def batch_slice(batch: int, ranks: Ranks) -> slice:
    """This rank's contiguous part of a global batch of ``batch`` samples (equal parts)."""
    if batch % ranks.world:
        raise InputError(
            f"the batch of {batch} does not split evenly over {ranks.world} processes "
            f"(torchrun --nproc_per_node); use a multiple of {ranks.world}"
        )
    n = batch // ranks.world
    return slice(ranks.rank * n, (ranks.rank + 1) * n)
