"""Training on several processes started by torchrun (gloo on CPU; optix_e2e.parallel):
2 processes follow the single process's path for the same global batch and seed, rank 0
alone writes, a run resumes, the training designs are split over the ranks without
duplicates. Each torchrun launch starts three interpreters, so the file keeps to four."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from optix_e2e import parallel
from optix_e2e.dataset import DatasetSettings, generate
from optix_e2e.surrogate import OpticsSurrogate

pytestmark = pytest.mark.slow  # whole design runs in subprocesses

HERE = Path(__file__).resolve().parent
TINY = [
    "--hidden",
    "32",
    "--depth",
    "2",
    "--base-channels",
    "16",
    "--batch",
    "32",
    "--val-designs",
    "8",
    "--val-every",
    "20",
    "--json",
]
# float32 gradients summed in another order (per rank, then across ranks): after 40 Adam
# steps the losses agree to about 1e-7 relative; 1e-4 leaves room and still catches a rank
# that computes the wrong samples (then they differ from the first step, by percents)
REL_TOL = 1e-4


def _torchrun(nproc: int, *args, spy: Path | None = None, out: Path | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if spy is not None:
        spy.mkdir(parents=True, exist_ok=True)
        env.update(OPTIX_SPY_DIR=str(spy), OPTIX_SPY_OUT=str(out))
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node",
        str(nproc),
        str(HERE / "ddp_spy.py") if spy is not None else "-m",
        *([] if spy is not None else ["optix_e2e"]),
        *args,
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    return res


def _single(*args) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run(
        [sys.executable, "-m", "optix_e2e", *args], capture_output=True, text=True, env=env, timeout=600
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return res


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ddp") / "data"
    generate("paper-triplet-v1", 48, 3, root, DatasetSettings(shard_size=16), progress=False)
    return root


@pytest.fixture(scope="module")
def one_process(data, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ddp") / "one"
    _single("surrogate", "train", str(data), "--out", str(out), "--steps", "40", *TINY)
    return out


def _history(run: Path) -> list[dict]:
    return json.loads((run / "train.json").read_text())["history"]


def test_two_processes_follow_the_single_process_resume_and_rank_0_alone_writes(data, one_process, tmp_path):
    """20 steps on 2 processes, then the same command with --steps 40 resumes from state.pt
    (the learning rate is still in its warm-up, 200 steps, so the path is the 40-step run's):
    the losses are the single process's at steps 20 and 40, the two models predict the same
    PSFs, and rank 0 alone wrote, in both launches."""
    out, spy = tmp_path / "two", tmp_path / "spy"
    args = ["surrogate", "train", str(data), "--out", str(out), *TINY]
    res = _torchrun(2, *args, "--steps", "20", spy=spy / "first", out=out)
    assert json.loads(res.stdout.strip().splitlines()[-1])["steps_done"] == 20  # rank 0 alone prints it
    res = _torchrun(2, *args, "--steps", "40", spy=spy / "resumed", out=out)
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    assert "resuming" in res.stderr and summary["processes"] == 2 and summary["steps_done"] == 40
    one, two = _history(one_process), _history(out)
    assert [h["step"] for h in two] == [h["step"] for h in one] == [20, 40]
    for a, b in zip(one, two):
        assert b["loss"] == pytest.approx(a["loss"], rel=REL_TOL)
        assert b["psf_rel_l1_median"] == pytest.approx(a["psf_rel_l1_median"], rel=REL_TOL)
    # the training moved by more than the tolerance (else agreeing would prove nothing)
    assert one[0]["loss"] != pytest.approx(one[1]["loss"], rel=5 * REL_TOL)
    # the two models predict the same PSFs (weights are compared through what they do: the
    # last layer's bias is a direction the unit-sum PSF ignores, where Adam moves on noise)
    m1, m2 = OpticsSurrogate.load(one_process / "surrogate.pt"), OpticsSurrogate.load(out / "surrogate.pt")
    params = torch.as_tensor(np.loadtxt(data / "designs.csv", delimiter=",", skiprows=1)[:8, 1:], dtype=torch.float32)
    with torch.no_grad():
        (p1, v1), (p2, v2) = m1.psfs(params, check=False), m2.psfs(params, check=False)
    torch.testing.assert_close(p2, p1, rtol=1e-3, atol=1e-6)
    torch.testing.assert_close(v2, v1, rtol=1e-3, atol=1e-6)
    # rank 0 wrote the checkpoints, the summary and the TensorBoard log; rank 1 nothing
    for launch in ("first", "resumed"):
        rank0 = json.loads((spy / launch / "rank0.json").read_text())
        assert json.loads((spy / launch / "rank1.json").read_text()) == [], launch
        for name in ("surrogate.pt", "state.pt", "train.json"):
            assert any(e.endswith(name) for e in rank0), (launch, name)
    assert len(list((out / "tb").iterdir())) >= 1
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in one_process.iterdir())


def test_training_designs_are_split_over_the_ranks_without_duplicates(data):
    """What each rank loads (train.rank_designs) covers the training designs once, none of
    the validation designs, and the global batch's samples go to exactly one rank, whose
    row d // W holds the design at global position d."""
    from optix_e2e.surrogate.data import design_indices
    from optix_e2e.surrogate.train import rank_designs

    designs, _ = design_indices(data)
    for world in (1, 2, 3):
        parts = [rank_designs(designs, 8, 0, r, world) for r in range(world)]
        tr, va = parts[0][0], parts[0][1]
        assert len(tr) == len(designs) - 8 and not set(tr.tolist()) & set(va.tolist())
        mine = [p[2] for p in parts]
        joined = np.sort(np.concatenate(mine))
        assert np.array_equal(joined, np.sort(tr)) and len(set(joined.tolist())) == len(joined)
        d = torch.randint(len(tr), (256,), generator=torch.Generator().manual_seed(0))
        owners = [(d % world == r) for r in range(world)]
        assert torch.equal(sum(o.int() for o in owners), torch.ones(256, dtype=torch.int32))
        for r in range(world):
            assert np.array_equal(mine[r][(d[owners[r]] // world).numpy()], tr[d[owners[r]].numpy()])
    with pytest.raises(ValueError, match="cannot be shared by 50 processes"):
        rank_designs(designs, 8, 0, 0, 50)


def test_max_designs_reads_no_shard_past_the_last_requested(data, tmp_path):
    """A run on the first designs of a dataset whose later shards are missing (still being
    generated) trains: the loader stops after the shard that holds the last design wanted."""
    from optix_e2e.surrogate.data import design_indices, load_arrays

    part = tmp_path / "part"
    shutil.copytree(data, part)
    shutil.rmtree(part / "shards" / "00002")
    designs, _ = design_indices(part, max_designs=20)
    arrays, _ = load_arrays(part, designs=designs[::2])
    assert np.array_equal(arrays.design, designs[::2])
    with pytest.raises(Exception, match="00002: shard missing"):
        load_arrays(part, designs=[40])


def test_an_explicit_gpu_index_is_refused_under_torchrun(monkeypatch):
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    with pytest.raises(ValueError, match="each process takes its own GPU"):
        parallel.setup("cuda:1")


def test_single_process_helpers_are_no_ops():
    ranks = parallel.setup("cpu")
    assert ranks.world == 1 and ranks.is_main and not ranks.distributed
    x = torch.tensor([1.0, 2.0])
    assert parallel.all_sum(x, ranks) is x and parallel.broadcast_value(3.5, ranks) == 3.5
    assert parallel.batch_slice(6, ranks) == slice(0, 6)
    assert parallel.batch_slice(6, parallel.Ranks(rank=1, world=2)) == slice(3, 6)
    with pytest.raises(ValueError, match="batch of 5 does not split evenly over 2 processes"):
        parallel.batch_slice(5, parallel.Ranks(rank=0, world=2))


# ----- optix design: the optimizers' gradient average, and a run under torchrun ----------------
def _toy(kind: str):
    """Two parameter blocks of a small regression, float64, and Alg. 1 (with its prox term)
    or vanilla over them; a batch of 8 samples."""
    from optix_e2e.camera_design.alg1 import Block, ProximalCompositional, Vanilla

    g = torch.Generator().manual_seed(0)
    x, y = torch.randn(8, 3, generator=g, dtype=torch.float64), torch.randn(8, generator=g, dtype=torch.float64)
    a = torch.nn.Parameter(torch.randn(3, generator=g, dtype=torch.float64))
    b = torch.nn.Parameter(torch.randn(1, generator=g, dtype=torch.float64))
    unused = torch.nn.Parameter(torch.ones(2, dtype=torch.float64))  # no gradient anywhere: Adam skips it
    blocks = [Block("a", [a], 0.05, steps=2, beta=0.5), Block("b", [b, unused], 0.1, steps=1, beta=0.2)]
    opt = ProximalCompositional(blocks, n_cycles=2, n_finetune=3) if kind == "alg1" else Vanilla(blocks, 0.05, 7)

    def loss(part: slice):
        r = torch.tanh(x[part] @ a) + b - y[part]
        return (r**2).mean(), {"l1": float(r.detach().abs().mean())}

    return [a, b, unused], opt, loss


def _toy_worker(rank: int, world: int, port: int, out: str) -> None:
    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world), LOCAL_RANK=str(rank)
    )
    ranks = parallel.setup("cpu")
    for kind in KINDS:
        params, opt, loss = _toy(kind)
        opt.reduce = lambda ps, task, info: parallel.average_step(ranks, ps, task, info)
        part = parallel.batch_slice(8, ranks)
        losses = [opt.step(lambda: loss(part))["loss"] for _ in range(opt.total_steps)]
        Path(out, f"{kind}-rank{rank}.json").write_text(
            json.dumps({"params": [p.tolist() for p in params], "loss": losses})
        )
    parallel.teardown()


KINDS = ("alg1", "vanilla")


def test_design_optimizers_average_gradients_over_processes(tmp_path):
    """Alg. 1 (block turns, prox terms, joint fine-tuning) and vanilla on 2 gloo processes
    (one spawn runs both), each on half of every batch, land where 1 process on the whole
    batches does (float64: to 1e-12), and report the whole batch's loss."""
    import socket

    import torch.multiprocessing as mp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    mp.spawn(_toy_worker, args=(2, port, str(tmp_path)), nprocs=2)
    for kind in KINDS:
        params, opt, loss = _toy(kind)
        ref_losses = [opt.step(lambda: loss(slice(0, 8)))["loss"] for _ in range(opt.total_steps)]
        for r in (0, 1):
            got = json.loads((tmp_path / f"{kind}-rank{r}.json").read_text())
            for p, q in zip(params, got["params"]):
                np.testing.assert_allclose(q, p.tolist(), rtol=1e-12, atol=1e-12, err_msg=kind)
            np.testing.assert_allclose(got["loss"], ref_losses, rtol=1e-6, err_msg=kind)  # float32 all-reduce
        assert not np.allclose(params[0].tolist(), _toy(kind)[0][0].tolist())  # the parameters moved


def test_a_design_run_under_torchrun_writes_from_rank_0(tmp_path):
    """A smoke design on 2 processes: rank 0 alone reports and writes, the trainings ran
    their steps. (Resuming: tests/camera_design/test_run_resume.py on one process, and the
    surrogate trainer's two-process resume above.)"""
    cfg = tmp_path / "b2.toml"
    cfg.write_text('batch = 2\noptics = "surrogate"\n')  # exact, the default, is one process's
    out, spy = tmp_path / "run", tmp_path / "spy"
    args = ["design", "iq-hardware", "--budget", "smoke", "--config", str(cfg), "--out", str(out), "--quiet"]
    res = _torchrun(2, *args, spy=spy, out=out)
    assert res.stdout.count('"results"') == 1  # rank 0 alone reports
    assert json.loads((spy / "rank1.json").read_text()) == []  # and writes
    assert any(e.endswith("results.json") for e in json.loads((spy / "rank0.json").read_text()))
    results = json.loads((out / "results.json").read_text())
    assert results["training"]["end_to_end"]["steps"] == 6 and np.isfinite(results["paired"]["psnr_db"]["mean"])


def test_a_batch_that_does_not_split_over_the_ranks_is_refused_before_anything_is_written(tmp_path):
    """What each rank of `optix design` under torchrun does first (run.claim_run_dir), here
    as rank 0 of 2 in this process: a batch of 3 is refused and no run directory appears."""
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.camera_design.run import claim_run_dir

    cfg = make_config("smoke", batch=3)
    with pytest.raises(ValueError, match="the batch of 3 does not split evenly over 2 processes"):
        claim_run_dir(tmp_path / "bad", cfg, parallel.Ranks(rank=0, world=2), progress=False, log=print)
    assert not (tmp_path / "bad").exists()
