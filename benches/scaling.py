#!/usr/bin/env python3
"""Scaling past one process: dataset designs/s against the number of Dask workers, and
surrogate training steps/s against the number of torchrun (DDP) processes.

    python benches/scaling.py --out results/scaling [--designs 1024] [--steps 300] [--workers 1 2]

Dataset: ``paper-triplet-v1`` at the dataset defaults (13 fields x RGB, 128 um at 1 um, the
sensor-pitch copy, FFT PSFs), shards of 64. Each configuration generates the same designs
into its own directory: one process with the engine on 1 and on all threads (its own
threading), and a Dask LocalCluster of W worker processes with 1 thread each (``optix
dataset --dask``). Every directory's verify digest must be the single-process one (the
bench stops otherwise). The Dask times include connecting to the running cluster and
checking its workers, not starting it or the workers' first import of the package (a
long-running cluster's start-up).

Surrogate: ``optix surrogate train`` on that dataset, the default network and global batch
of 256, ``--steps`` steps: 1 process on 1 thread and on all threads, and ``torchrun
--nproc_per_node P`` with 1 thread per process. steps/s is the steps over the training
loop's time (train.json, data loading excluded); the final training loss of each run is
reported beside it (the same path whatever P, to float rounding).

Writes scaling.json, scaling.csv and scaling.png into --out and prints the JSON. It
measures; it asserts nothing about speed. On a GPU machine, add ``--device cuda`` for the
surrogate part (NCCL).
"""

from __future__ import annotations

import argparse
import csv
import importlib
import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

SPACE = "paper-triplet-v1"


def _env(threads: int | None) -> dict:
    env = dict(os.environ)
    for v in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(v, None)
        if threads:
            env[v] = str(threads)
    return env


def _run(cmd: list[str], env: dict) -> subprocess.CompletedProcess:
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{res.stderr[-3000:]}")
    return res


def _digest(root: Path) -> str:
    from optix_e2e.dataset import verify

    rep = verify(root, check_hashes=False)
    if not rep["ok"]:
        sys.exit(f"{root}: {rep['problems']} missing {rep['missing_shards']}")
    return rep["digest"]


def dataset_rows(work: Path, n: int, workers: list[int]) -> tuple[list[dict], Path]:
    import distributed

    from optix_e2e.dataset import DatasetSettings, generate
    from optix_e2e.dataset.cluster import WORKER_ENV

    rows, ref = [], None
    gen_args = [SPACE, "-n", str(n), "--seed", "0"]
    for threads in (1, os.cpu_count() or 1):
        root = work / f"single_t{threads}"
        shutil.rmtree(root, ignore_errors=True)
        res = _run([sys.executable, "-m", "optix_e2e", "dataset", *gen_args, "--out", str(root)], _env(threads))
        rep = json.loads(res.stdout.strip().splitlines()[-1])
        d = _digest(root)
        ref = ref or d
        rows.append(
            {
                "what": "dataset",
                "how": "one process",
                "units": 1,
                "threads_per_unit": threads,
                "seconds": rep["seconds"],
                "rate": rep["designs_per_s"],
                "rate_unit": "designs/s",
                "same_digest": d == ref,
            }
        )
        print(f"dataset, one process, {threads} thread(s): {rep['designs_per_s']:.1f} designs/s", file=sys.stderr)
    for w in workers:
        root = work / f"dask_w{w}"
        shutil.rmtree(root, ignore_errors=True)
        with distributed.LocalCluster(
            n_workers=w, threads_per_worker=1, processes=True, dashboard_address=None, env={v: "1" for v in WORKER_ENV}
        ) as cluster:
            with distributed.Client(cluster.scheduler_address) as client:  # workers import the package first
                client.run(importlib.import_module, "optix_e2e.dataset.cluster")
            # seconds from after the sampling (the client's, as in one process) to the last shard
            rep = generate(SPACE, n, 0, root, DatasetSettings(), progress=False, dask=cluster.scheduler_address)
            sec = rep.seconds
        if rep.shard_errors:
            sys.exit(f"dask with {w} workers: {rep.shard_errors}")
        d = _digest(root)
        if d != ref:
            sys.exit(f"dask with {w} workers: digest {d} differs from the single process's {ref}")
        rows.append(
            {
                "what": "dataset",
                "how": "Dask LocalCluster",
                "units": w,
                "threads_per_unit": 1,
                "seconds": sec,
                "rate": n / sec,
                "rate_unit": "designs/s",
                "same_digest": True,
            }
        )
        print(f"dataset, Dask, {w} worker(s) x 1 thread: {n / sec:.1f} designs/s", file=sys.stderr)
    return rows, work / "single_t1"


def surrogate_rows(work: Path, data: Path, steps: int, procs: list[int], device: str) -> list[dict]:
    rows = []
    common = [
        "surrogate",
        "train",
        str(data),
        "--steps",
        str(steps),
        "--val-every",
        str(10 * steps),
        "--val-designs",
        "64",
        "--device",
        device,
        "--json",
    ]
    runs = [("one process", 1, t) for t in sorted({1, os.cpu_count() or 1})] + [("torchrun DDP", p, 1) for p in procs]
    for how, p, threads in runs:
        out = work / f"sur_{how.split()[0]}_p{p}_t{threads}"
        shutil.rmtree(out, ignore_errors=True)
        if how == "one process":
            cmd = [sys.executable, "-m", "optix_e2e", *common, "--out", str(out)]
        else:
            cmd = [
                sys.executable,
                "-m",
                "torch.distributed.run",
                "--standalone",
                "--nproc_per_node",
                str(p),
                "-m",
                "optix_e2e",
                *common,
                "--out",
                str(out),
            ]
        _run(cmd, _env(threads))
        summary = json.loads((out / "train.json").read_text())
        sec = summary["seconds"]
        rows.append(
            {
                "what": "surrogate training",
                "how": how,
                "units": p,
                "threads_per_unit": threads,
                "seconds": sec,
                "rate": summary["steps_done"] / sec,
                "rate_unit": "steps/s",
                "final_loss": summary["history"][-1]["loss"],
                "device": summary["device"],
            }
        )
        print(
            f"surrogate, {how}, {p} process(es) x {threads} thread(s): {rows[-1]['rate']:.2f} steps/s, "
            f"loss {rows[-1]['final_loss']:.5f}",
            file=sys.stderr,
        )
    return rows


def chart(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, what in zip(axes, ("dataset", "surrogate training")):
        rs = [r for r in rows if r["what"] == what]
        labels = [f"{r['how']}\n{r['units']} x {r['threads_per_unit']} thr" for r in rs]
        ax.bar(
            range(len(rs)),
            [r["rate"] for r in rs],
            color=["#999" if r["units"] == 1 and r["how"].startswith("one") else "#3a7" for r in rs],
        )
        ax.set_xticks(range(len(rs)), labels, fontsize=7)
        ax.set_ylabel(rs[0]["rate_unit"] if rs else "")
        ax.set_title(what)
        for i, r in enumerate(rs):
            ax.text(i, r["rate"], f"{r['rate']:.1f}", ha="center", va="bottom", fontsize=8)
    fig.suptitle(f"{platform.node()}: {os.cpu_count()} cores")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--designs", type=int, default=1024)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--procs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--device", default="cpu", help="surrogate training device (cuda: NCCL)")
    ap.add_argument("--parts", nargs="+", choices=["dataset", "surrogate"], default=["dataset", "surrogate"])
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    work = a.out / "work"
    work.mkdir(exist_ok=True)
    rows, data = dataset_rows(work, a.designs, a.workers if "dataset" in a.parts else [])
    if "surrogate" in a.parts:
        rows += surrogate_rows(work, data, a.steps, a.procs, a.device)
    result = {
        "machine": {"node": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "space": SPACE,
        "designs": a.designs,
        "steps": a.steps,
        "rows": rows,
    }
    name = "scaling" if len(a.parts) == 2 else f"scaling_{a.parts[0]}"
    (a.out / f"{name}.json").write_text(json.dumps(result, indent=2))
    with open(a.out / f"{name}.csv", "w", newline="") as f:
        keys = ["what", "how", "units", "threads_per_unit", "seconds", "rate", "rate_unit", "same_digest", "final_loss"]
        w = csv.DictWriter(f, keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    chart(rows, a.out / f"{name}.png")
    shutil.rmtree(work)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
