"""Algorithm 1 of the paper (Sec. 5.2): proximal compositional optimization over parameter
blocks, and the vanilla baseline of Sec. 6.3.

Alg. 1: n_c cycles; in each, every block i in turn takes n_i steps of its own optimizer (Adam,
its own learning rate) on L_TASK + L_PROX while the other blocks stay fixed; then n_f joint
steps of every block's optimizer on L_TASK alone.

How we read Eq. 15, L_PROX = beta_i ||P_i(t) - P_i(t+1)||^2. Following the block proximal
update it cites (Xu & Yin 2013, Eq. 1.3b: P_i^k = argmin_P L(P) + beta/2 ||P - P_i^(k-1)||^2),
P_i(t) is the block's value when its turn in cycle t begins (a constant, the anchor) and
P_i(t+1) the value being optimized during the turn. The n_i steps are a few gradient steps on
that proximal problem: L' = L_TASK + beta_i ||P_i - anchor_i||^2. (Reading P_i(t) as the
value before every single step would make the term's gradient zero at each step, i.e. no
term at all.) A larger beta_i keeps the turn's result closer to where it began.

P_i is measured in the block's own coordinates (``Block.coords``): for the lens parameters and
the hardware ISP's hyperparameters, their range-normalized values in [0, 1] (the sigmoid of
what the optimizer moves), so beta weighs the same fraction of every range alike; for network
weights, the weights.

Both optimizers step one at a time (``step(loss_fn)``) so a run can be checkpointed at any
step: ``state_dict`` holds the step counter, the Adam moments and the current anchor.

Data-parallel runs (torchrun) set ``reduce``: called after backward with the parameters
about to step, the task loss and the loss's info, it averages the gradients over the
processes (optix_e2e.parallel.average_step) and returns the averaged loss and info.
``before_step``, when set, is called next with the same parameters and may change their
gradients (the manufacturability barrier, camera_design/guard.py); the dict it returns joins
the step's info.

``scaler`` (``--precision fp16``: a torch.amp.GradScaler; None otherwise) scales the loss before
backward; the gradients are unscaled after ``reduce`` (so every process sees the same averaged
gradients and skips alike) and before ``before_step``; a step whose gradients overflowed is
skipped by the scaler (the step counter still moves: the schedule is in steps taken, not updates).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import nn

from ..errors import InputError, RunError


@dataclass
class Block:
    """One parameter block: its parameters, Adam learning rate, steps per turn, prox weight and
    the coordinates the prox term measures (``coords``: tensor -> tensor, default identity)."""

    name: str
    params: list[nn.Parameter]
    lr: float
    steps: int = 1
    beta: float = 0.0
    coords: Callable[[torch.Tensor], torch.Tensor] | None = None

    def coord(self, p: torch.Tensor) -> torch.Tensor:
        return p if self.coords is None else self.coords(p)


def _adam_steps(opt: torch.optim.Optimizer, params) -> int:
    """How many steps ``opt`` has applied to the block of ``params``: its state's step count,
    the most over the block's parameters (one that never had a gradient was never stepped)."""
    n = 0
    for p in params:
        step = opt.state.get(p, {}).get("step")
        if step is not None:
            n = max(n, int(step))
    return n


def _set_trainable(blocks: list[Block], active: set[str]) -> None:
    """Only the active blocks' parameters need gradients: the others' weight gradients are
    not computed (the backward pass still runs through their stages)."""
    for b in blocks:
        for p in b.params:
            p.requires_grad_(b.name in active)


def _backward(loss: torch.Tensor, scaler) -> None:
    (loss if scaler is None else scaler.scale(loss)).backward()


def _unscale(opts, scaler) -> None:
    if scaler is not None:
        for o in opts:
            scaler.unscale_(o)


def _step(opts, scaler) -> None:
    """Each optimizer's step (through the scaler: skipped where its gradients overflowed)."""
    for o in opts:
        if scaler is None:
            o.step()
        else:
            scaler.step(o)
    if scaler is not None:
        scaler.update()


def _scaler_state(scaler) -> dict:
    """The scaler's state for a checkpoint (nothing without one: fp32 checkpoints as before)."""
    return {} if scaler is None else {"scaler": scaler.state_dict()}


def _load_scaler(scaler, st: dict) -> None:
    if scaler is not None and isinstance(st.get("scaler"), dict):
        scaler.load_state_dict(st["scaler"])


class ProximalCompositional:
    """Alg. 1. ``step(loss_fn)`` runs one optimizer step; ``loss_fn()`` returns the task loss
    (a 0-d tensor, or a (loss, info dict) pair). ``total_steps`` = n_c sum(n_i) + n_f."""

    kind = "alg1"

    def __init__(self, blocks: list[Block], n_cycles: int, n_finetune: int):
        if not blocks:
            raise InputError("Alg. 1 needs at least one parameter block")
        names = [b.name for b in blocks]
        if len(set(names)) != len(names):
            raise InputError(f"block names must be unique, got {names}")
        for b in blocks:
            if b.steps < 1 or b.lr <= 0 or b.beta < 0:
                raise InputError(
                    f"block {b.name}: steps >= 1, lr > 0 and beta >= 0 required (got {b.steps}, {b.lr}, {b.beta})"
                )
        if n_cycles < 0 or n_finetune < 0:
            raise InputError("n_cycles and n_finetune must be >= 0")
        self.blocks, self.n_cycles, self.n_finetune = blocks, int(n_cycles), int(n_finetune)
        self.opts = {b.name: torch.optim.Adam(b.params, lr=b.lr) for b in blocks}
        self.t = 0
        self.anchor: list[torch.Tensor] | None = None
        self.reduce: Callable | None = None
        self.before_step: Callable | None = None
        self.scaler = None  # fp16's torch.amp.GradScaler (module doc)

    @property
    def cycle_len(self) -> int:
        return sum(b.steps for b in self.blocks)

    @property
    def total_steps(self) -> int:
        return self.n_cycles * self.cycle_len + self.n_finetune

    def phase(self, t: int | None = None) -> tuple[str, Block | None, bool]:
        """(kind, active block, first step of its turn) at step t: kind "cycle" or "finetune"."""
        t = self.t if t is None else t
        if t < self.n_cycles * self.cycle_len:
            k = t % self.cycle_len
            for b in self.blocks:
                if k < b.steps:
                    return "cycle", b, k == 0
                k -= b.steps
        return "finetune", None, False

    def block_at(self, t: int) -> str:
        """The block step t (0-based) updates, "all" in the joint fine-tuning (history's ``block``)."""
        _, block, _ = self.phase(t)
        return block.name if block is not None else "all"

    def scheduled_updates(self) -> dict[str, int]:
        """The updates each block gets over the whole schedule: n_c n_i + n_f."""
        return {b.name: self.n_cycles * b.steps + self.n_finetune for b in self.blocks}

    def updates(self) -> dict[str, int]:
        """The updates each block has had so far (its Adam's step count, across resumes)."""
        return {b.name: _adam_steps(self.opts[b.name], b.params) for b in self.blocks}

    def step(self, loss_fn) -> dict:
        if self.t >= self.total_steps:
            raise RunError(f"Alg. 1 has run all its {self.total_steps} steps")
        kind, block, first = self.phase()
        if kind == "cycle":
            if block.beta > 0 and (first or self.anchor is None):
                self.anchor = [block.coord(p.detach()).clone() for p in block.params]
            _set_trainable(self.blocks, {block.name})
            opts = [self.opts[block.name]]
        else:
            self.anchor = None
            _set_trainable(self.blocks, {b.name for b in self.blocks})
            opts = list(self.opts.values())
        for o in opts:
            o.zero_grad(set_to_none=True)
        out = loss_fn()
        task, info = out if isinstance(out, tuple) else (out, {})
        loss = task
        prox = None
        if kind == "cycle" and block.beta > 0:  # Eq. 15
            prox = block.beta * sum(((block.coord(p) - a) ** 2).sum() for p, a in zip(block.params, self.anchor))
            loss = task + prox
        _backward(loss, self.scaler)
        params = [p for o in opts for g in o.param_groups for p in g["params"]]
        if self.reduce is not None:
            task, info = self.reduce(params, task, info)
        _unscale(opts, self.scaler)
        if self.before_step is not None:
            info = {**info, **self.before_step(params)}
        _step(opts, self.scaler)
        self.t += 1
        return {
            "step": self.t,
            "phase": kind,
            "block": block.name if block else "all",
            "loss": float(task.detach()),
            "prox": float(prox.detach()) if prox is not None else 0.0,
            **info,
        }

    def state_dict(self) -> dict:
        return {
            "kind": self.kind,
            "t": self.t,
            "opts": {k: o.state_dict() for k, o in self.opts.items()},
            "anchor": self.anchor,
            **_scaler_state(self.scaler),
        }

    def load_state_dict(self, st: dict) -> None:
        if not isinstance(st, dict) or st.get("kind") != self.kind:
            raise InputError(
                f"optimizer state is for {st.get('kind') if isinstance(st, dict) else st!r}, not {self.kind!r}"
            )
        if set(st.get("opts", {})) != set(self.opts):
            raise InputError(f"optimizer state has blocks {sorted(st.get('opts', {}))}, this run {sorted(self.opts)}")
        self.t = int(st["t"])
        for k, o in self.opts.items():
            o.load_state_dict(st["opts"][k])
        self.anchor = st.get("anchor")
        _load_scaler(self.scaler, st)


class Vanilla:
    """The baseline of Sec. 6.3: one Adam over every parameter with one learning rate, all
    blocks at every step, no alternation, no proximal term; ``total_steps`` steps."""

    kind = "vanilla"

    def __init__(self, blocks: list[Block], lr: float, total_steps: int):
        if lr <= 0 or total_steps < 0:
            raise InputError("vanilla: lr > 0 and total_steps >= 0 required")
        self.blocks, self.lr, self._total = blocks, float(lr), int(total_steps)
        self.opt = torch.optim.Adam([p for b in blocks for p in b.params], lr=self.lr)
        self.t = 0
        self.reduce: Callable | None = None
        self.before_step: Callable | None = None
        self.scaler = None  # fp16's torch.amp.GradScaler (module doc)

    @property
    def total_steps(self) -> int:
        return self._total

    def phase(self, t: int | None = None):
        return "joint", None, False

    def block_at(self, t: int) -> str:
        return "all"

    def scheduled_updates(self) -> dict[str, int]:
        """Every block at every step."""
        return {b.name: self.total_steps for b in self.blocks}

    def updates(self) -> dict[str, int]:
        return {b.name: _adam_steps(self.opt, b.params) for b in self.blocks}

    def step(self, loss_fn) -> dict:
        if self.t >= self.total_steps:
            raise RunError(f"vanilla has run all its {self.total_steps} steps")
        _set_trainable(self.blocks, {b.name for b in self.blocks})
        self.opt.zero_grad(set_to_none=True)
        out = loss_fn()
        task, info = out if isinstance(out, tuple) else (out, {})
        _backward(task, self.scaler)
        params = [p for g in self.opt.param_groups for p in g["params"]]
        if self.reduce is not None:
            task, info = self.reduce(params, task, info)
        _unscale([self.opt], self.scaler)
        if self.before_step is not None:
            info = {**info, **self.before_step(params)}
        _step([self.opt], self.scaler)
        self.t += 1
        return {"step": self.t, "phase": "joint", "block": "all", "loss": float(task.detach()), "prox": 0.0, **info}

    def state_dict(self) -> dict:
        return {"kind": self.kind, "t": self.t, "opt": self.opt.state_dict(), **_scaler_state(self.scaler)}

    def load_state_dict(self, st: dict) -> None:
        if not isinstance(st, dict) or st.get("kind") != self.kind:
            raise InputError(
                f"optimizer state is for {st.get('kind') if isinstance(st, dict) else st!r}, not {self.kind!r}"
            )
        self.t = int(st["t"])
        self.opt.load_state_dict(st["opt"])
        _load_scaler(self.scaler, st)
