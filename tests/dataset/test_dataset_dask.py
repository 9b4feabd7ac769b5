"""``optix dataset ... --dask``: shards as Dask tasks give the dataset a single process
writes (the same verify digest, the same bytes), also when a worker is killed mid-shard;
task failures are collected per shard and a second run redoes them."""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from optix_e2e.cli.dataset import dataset
from optix_e2e.dataset import DatasetSettings, generate, verify
from optix_e2e.dataset.cluster import WORKER_ENV, ClusterError, parse_address

distributed = pytest.importorskip("distributed")

# Huygens PSFs make a shard of 24 designs take about half a second on one thread: long
# enough to kill a worker while it computes one
N, SEED = 96, 5
SETTINGS = DatasetSettings(n_fields=3, window_um=32.0, pupil_samples=32, shard_size=24, psf_method="huygens")
CLI_ARGS = [
    "paper-triplet",
    "-n",
    str(N),
    "--seed",
    str(SEED),
    "--fields",
    "3",
    "--window-um",
    "32",
    "--pupil-samples",
    "32",
    "--shard-size",
    "24",
    "--psf-method",
    "huygens",
]


def _arrays(root: Path) -> dict:
    return {
        f"{d.name}/{f.name}": f.read_bytes()
        for d in sorted((root / "shards").iterdir())
        for f in sorted(d.glob("*.npy"))
    }


@pytest.fixture(scope="module")
def single(tmp_path_factory) -> Path:
    """The same dataset written by one process, no Dask."""
    root = tmp_path_factory.mktemp("single") / "ds"
    rep = generate("paper-triplet", N, SEED, root, SETTINGS, progress=False)
    assert rep.shards_written == [0, 1, 2, 3] and rep.n_ok == N
    return root


@pytest.fixture
def cluster():
    c = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, env={v: "1" for v in WORKER_ENV}
    )
    yield c
    c.close()


def test_two_worker_local_cluster_has_the_digest_of_a_single_process(single, tmp_path):
    root = tmp_path / "ds"
    res = CliRunner().invoke(dataset, [*CLI_ARGS, "--out", str(root), "--dask", "local:2"])
    assert res.exit_code == 0, res.output
    assert _arrays(root) == _arrays(single)
    assert verify(root)["digest"] == verify(single)["digest"]
    assert not [p for p in (root / "shards").iterdir() if p.name.startswith(".")]
    # finished: the same command computes nothing
    rep = generate("paper-triplet", N, SEED, root, SETTINGS, progress=False, dask="local:1")
    assert rep.shards_written == [] and rep.shards_skipped == [0, 1, 2, 3]


def test_a_worker_killed_mid_shard_loses_nothing(single, tmp_path, cluster):
    """SIGKILL a worker process while it computes a shard: the scheduler gives the task to
    a worker again, and the finished dataset is byte-identical to a single process's."""
    root = tmp_path / "ds"
    box: dict = {}

    def run():
        try:
            box["rep"] = generate(
                "paper-triplet", N, SEED, root, SETTINGS, progress=False, dask=cluster.scheduler_address
            )
        except BaseException as exc:  # reported below
            box["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    killed: list[int] = []  # the unfinished shards the killed worker held (one of them running)
    with distributed.Client(cluster.scheduler_address) as client:
        deadline = time.time() + 120
        while not killed and time.time() < deadline and t.is_alive():
            for addr, keys in client.processing().items():
                held = [int(str(key).rsplit("-", 1)[1]) for key in keys]
                held = [k for k in held if not (root / "shards" / f"{k:05d}").exists()]
                if held:  # a 1-thread worker with unfinished shards is computing one of them
                    pid = client.run(os.getpid, workers=[addr])[addr]
                    os.kill(pid, signal.SIGKILL)
                    killed = held
                    break
            time.sleep(0.01)
    t.join(300)
    assert killed, "no shard was caught in flight"
    assert "error" not in box, box.get("error")
    rep = box["rep"]
    assert rep.shard_errors == [] and rep.n_ok == N
    assert set(killed) <= set(rep.shards_written)
    assert _arrays(root) == _arrays(single)
    assert verify(root)["digest"] == verify(single)["digest"]
    assert not [p for p in (root / "shards").iterdir() if p.name.startswith(".")]


@pytest.mark.slow
def test_task_failures_are_collected_and_a_second_run_redoes_them(single, tmp_path, cluster):
    root = tmp_path / "ds"
    generate("paper-triplet", N, SEED, root, SETTINGS, progress=False, shards="0")
    shutil.rmtree(root / "shards")
    (root / "shards").write_text("not a directory")  # no worker can write a shard
    rep = generate("paper-triplet", N, SEED, root, SETTINGS, progress=False, dask=cluster.scheduler_address)
    assert [e["shard"] for e in rep.shard_errors] == [0, 1, 2, 3]
    assert all("FileExistsError" in e["error"] or "NotADirectoryError" in e["error"] for e in rep.shard_errors)
    res = CliRunner().invoke(dataset, [*CLI_ARGS, "--out", str(root), "--dask", cluster.scheduler_address])
    assert res.exit_code == 1 and "4 shard(s) failed on the cluster (0, 1, 2, 3" in res.output
    (root / "shards").unlink()
    rep = generate("paper-triplet", N, SEED, root, SETTINGS, progress=False, dask=cluster.scheduler_address)
    assert rep.shard_errors == [] and rep.shards_written == [0, 1, 2, 3]
    assert verify(root)["digest"] == verify(single)["digest"]


def test_a_task_refuses_a_worker_that_sees_another_directory_or_build(single):
    from optix_e2e.dataset.cluster import _identity, run_shard

    me = _identity(str(single))
    with pytest.raises(ClusterError, match="another optix-e2e build"):
        run_shard(str(single), 0, {**me, "engine": "0" * 16})
    with pytest.raises(ClusterError, match="must be on storage shared by the client and every worker"):
        run_shard(str(single), 0, {**me, "manifest": "0" * 64})
    assert run_shard(str(single), 0, me)["written"] is False  # complete already: left alone


def test_addresses():
    assert parse_address("local:3") == ("local", 3)
    assert parse_address("tcp://10.0.0.1:8786") == ("address", "tcp://10.0.0.1:8786")
    assert parse_address("localhost:8786") == ("address", "tcp://localhost:8786")
    assert parse_address("tcp://proj_scheduler_1:8786") == ("address", "tcp://proj_scheduler_1:8786")  # compose
    for bad, msg in [
        ("local:0", "1 <= N <= 256"),
        ("local:x", "1 <= N"),
        ("local:50000", "1 <= N <= 256"),
        ("/nowhere/scheduler.json", "no such scheduler file"),
        # checked before any connection is tried (these waited 30 s or raised inside dask)
        ("tcp://256.1.1.1:1", "'256.1.1.1' is not an IP address"),
        ("udp://10.0.0.1:1", "'udp' is not one of dask's"),
        ("tcp://10.0.0.1:0", "port from 1 to 65535"),
        ("tcp://10.0.0.1", "HOST:PORT"),
    ]:
        with pytest.raises(ClusterError, match=msg):
            parse_address(bad)


def test_a_scheduler_file_is_read_and_checked_before_connecting(tmp_path):
    sched = tmp_path / "scheduler.json"
    sched.write_text(json.dumps({"type": "Scheduler", "address": "tcp://10.0.0.5:8786"}))
    assert parse_address(str(sched)) == ("address", "tcp://10.0.0.5:8786")
    for text, msg in (
        ("", "not a scheduler file"),
        ("garbage{", "not a scheduler file"),
        ("[]", 'no "address"'),
        ('{"address": "tcp://999.0.0.1:1"}', "its address: '999.0.0.1'"),
    ):
        sched.write_text(text)
        with pytest.raises(ClusterError, match=msg):
            parse_address(str(sched))
    os.mkfifo(tmp_path / "pipe.json")
    with pytest.raises(ClusterError, match="not a regular file"):
        parse_address(str(tmp_path / "pipe.json"))


def test_cli_names_a_bad_address(tmp_path):
    res = CliRunner().invoke(dataset, [*CLI_ARGS, "--out", str(tmp_path / "ds"), "--dask", "local:0"])
    assert res.exit_code == 1 and "Error: --dask 'local:0': expected local:N" in res.output
    assert not (tmp_path / "ds").exists()
    assert "Traceback" not in res.output
