"""Algorithm 1 (optix_e2e.camera_design.alg1) on a toy composition of three blocks with a known
optimum: turns, the proximal term (Eq. 15), fine-tuning, the vanilla baseline."""

from __future__ import annotations

import copy

import pytest
import torch
from torch import nn

from optix_e2e.camera_design.alg1 import Block, ProximalCompositional, Vanilla

pytestmark = pytest.mark.usefixtures("one_torch_thread")

X = torch.linspace(-1.0, 1.0, 17)
TARGET = 2.0 * (3.0 * X + 1.0) + 0.5  # f3(f2(f1(x))) with a = 3, b = 1, c = 2, d = 0.5


class Toy(nn.Module):
    """f1 = a x, f2 = y + b, f3 = c z + d: three blocks {a}, {b}, {c, d}."""

    def __init__(self):
        super().__init__()
        self.a, self.b = nn.Parameter(torch.tensor(1.0)), nn.Parameter(torch.tensor(0.0))
        self.c, self.d = nn.Parameter(torch.tensor(1.0)), nn.Parameter(torch.tensor(0.0))

    def blocks(self, steps=5, beta=0.0, lr=0.05):
        return [
            Block("f1", [self.a], lr, steps, beta),
            Block("f2", [self.b], lr, steps, beta),
            Block("f3", [self.c, self.d], lr, steps, beta),
        ]

    def loss(self):
        return ((self.c * (self.a * X + self.b) + self.d - TARGET) ** 2).mean()

    def snapshot(self):
        return {k: v.detach().clone() for k, v in self.named_parameters()}


def test_only_the_active_block_moves_during_its_turn_and_the_schedule_is_round_robin():
    toy = Toy()
    opt = ProximalCompositional(toy.blocks(steps=3, beta=0.1), n_cycles=2, n_finetune=4)
    assert opt.total_steps == 2 * 9 + 4
    owner = {"a": "f1", "b": "f2", "c": "f3", "d": "f3"}
    seen = []
    for _ in range(2 * 9):
        before = toy.snapshot()
        info = opt.step(toy.loss)
        seen.append(info["block"])
        after = toy.snapshot()
        for k in before:
            if owner[k] == info["block"]:
                continue
            assert torch.equal(before[k], after[k]), (info, k)
        assert any(not torch.equal(before[k], after[k]) for k in before if owner[k] == info["block"])
    assert seen == (["f1"] * 3 + ["f2"] * 3 + ["f3"] * 3) * 2
    # fine-tuning: every block moves at every step, no proximal term
    before = toy.snapshot()
    info = opt.step(toy.loss)
    assert info["phase"] == "finetune" and info["prox"] == 0.0
    after = toy.snapshot()
    assert all(not torch.equal(before[k], after[k]) for k in before)
    with pytest.raises(RuntimeError):
        for _ in range(4):
            opt.step(toy.loss)


def test_the_proximal_term_shrinks_a_turn_as_beta_grows():
    moves = []
    for beta in (0.0, 1.0, 10.0, 100.0):
        toy = Toy()
        opt = ProximalCompositional(toy.blocks(steps=40, beta=beta, lr=0.05), n_cycles=1, n_finetune=0)
        for _ in range(40):  # block f1's whole turn
            opt.step(toy.loss)
        moves.append(abs(toy.a.item() - 1.0))
    assert moves == sorted(moves, reverse=True) and moves[-1] < 0.2 * moves[0], moves


def test_alg1_reaches_the_known_optimum_and_vanilla_starts_from_the_same_point():
    torch.manual_seed(0)
    toy = Toy()
    opt = ProximalCompositional(toy.blocks(steps=20, beta=0.01, lr=0.05), n_cycles=15, n_finetune=300)
    start = toy.snapshot()
    for _ in range(opt.total_steps):
        opt.step(toy.loss)
    assert toy.loss().item() < 1e-3
    # the composition's optimum: c a = 6, c b + d = 2.5
    assert abs(toy.c.item() * toy.a.item() - 6.0) < 0.05
    assert abs(toy.c.item() * toy.b.item() + toy.d.item() - 2.5) < 0.05
    van = Toy()
    assert all(torch.equal(start[k], v) for k, v in van.snapshot().items())
    v = Vanilla(van.blocks(), lr=0.05, total_steps=opt.total_steps)
    first = v.step(van.loss)
    assert first["block"] == "all" and all(not torch.equal(start[k], x) for k, x in van.snapshot().items())


def test_state_dict_resumes_on_the_same_path():
    a, b = Toy(), Toy()
    oa = ProximalCompositional(a.blocks(steps=3, beta=1.0), n_cycles=3, n_finetune=3)
    for _ in range(7):  # stop inside block f3's turn
        oa.step(a.loss)
    st = copy.deepcopy({"opt": oa.state_dict(), "model": a.state_dict()})  # as torch.save would
    for _ in range(5):
        oa.step(a.loss)
    b.load_state_dict(st["model"])
    ob = ProximalCompositional(b.blocks(steps=3, beta=1.0), n_cycles=3, n_finetune=3)
    ob.load_state_dict(st["opt"])
    for _ in range(5):
        ob.step(b.loss)
    assert all(torch.equal(x, y) for x, y in zip(a.parameters(), b.parameters()))
    with pytest.raises(ValueError, match="vanilla"):
        Vanilla(b.blocks(), 0.1, 3).load_state_dict(st["opt"])


def test_bad_blocks_are_refused():
    toy = Toy()
    with pytest.raises(ValueError, match="unique"):
        ProximalCompositional([Block("x", [toy.a], 0.1), Block("x", [toy.b], 0.1)], 1, 0)
    with pytest.raises(ValueError, match="lr"):
        ProximalCompositional([Block("x", [toy.a], 0.0)], 1, 0)
