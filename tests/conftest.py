"""Shared fixtures: the bundled Cooke triplet and the data in ../shared.

The shared data (reference/, zmx-samples/, lpips-reference/) is looked up in <repo
root>/../shared (CI clones the repo with shared/ beside it), or in $OPTIX_SHARED_DIR; one
folder can be pointed elsewhere alone (OPTIX_REFERENCE_DIR, OPTIX_ZMX_SAMPLES_DIR).  A
missing folder is a test failure with a message, never a silent skip.
"""

from __future__ import annotations

import importlib.util
import json
import os
import traceback
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_dir(name: str, env: str | None = None) -> Path:
    """The shared data folder ``name``: $``env`` if set, else $OPTIX_SHARED_DIR/``name``, else
    <repo root>/../shared/``name``."""
    if env and os.environ.get(env):
        return Path(os.environ[env])
    root = os.environ.get("OPTIX_SHARED_DIR")
    return (Path(root) if root else REPO_ROOT.parent / "shared") / name


@pytest.fixture(autouse=True)
def _release_held_folders():
    """A test that calls the package's functions directly lets go of the --out folders they
    held (io.hold_out_dir), as the end of a command does."""
    yield
    from optix_e2e.io import release_out_dirs

    release_out_dirs()


#: how a missing shared folder is to be found (the failure message)
WHERE_SHARED = "clone the repository with shared/ beside it or set OPTIX_SHARED_DIR"


def reference_dir() -> Path:
    return shared_dir("reference", "OPTIX_REFERENCE_DIR")


@pytest.fixture(scope="session")
def ref_dir() -> Path:
    path = reference_dir()
    if not (path / "cooke_triplet_reference.json").is_file():
        pytest.fail(
            f"reference data not found at {path}: {WHERE_SHARED} (or OPTIX_REFERENCE_DIR)",
            pytrace=False,
        )
    return path


@pytest.fixture(scope="session")
def ref_prescription(ref_dir) -> dict:
    return json.loads((ref_dir / "cooke_triplet.json").read_text())


@pytest.fixture(scope="session")
def ref_data(ref_dir) -> dict:
    return json.loads((ref_dir / "cooke_triplet_reference.json").read_text())


@pytest.fixture(scope="session")
def ref_psf_meta(ref_dir) -> dict:
    return json.loads((ref_dir / "psf" / "psf_meta.json").read_text())


@pytest.fixture(scope="session")
def cooke():
    from optix_e2e.lens import Lens

    return Lens.load("cooke-f50")


@pytest.fixture(scope="module")
def one_torch_thread():
    """Small tensors: one torch thread is fastest and immune to a busy shared CPU."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@dataclass
class CliRun:
    """What an `optix` command gave: exit status, stdout, stderr (like subprocess.run's)."""

    returncode: int
    stdout: str
    stderr: str


def _optix_in_process(*args: str) -> CliRun:
    """`optix ARGS` in this process through click's test runner: what the command prints and
    exits with, without a new interpreter importing torch again (10-15 s a design run). A bug
    (an exception the CLI does not turn into one line) comes back as its traceback in stderr."""
    import torch
    from click.testing import CliRunner

    from optix_e2e.cli import main

    threads = torch.get_num_threads()  # --threads sets the process's torch threads
    try:
        res = CliRunner().invoke(main, [str(a) for a in args])
    finally:
        torch.set_num_threads(threads)
    err = res.stderr
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        err += "".join(traceback.format_exception(*res.exc_info))
    return CliRun(res.exit_code, res.stdout, err)


@pytest.fixture(scope="session")
def optix():
    """Run an `optix` command in this process: ``optix("design", "iq-software", ...)``."""
    return _optix_in_process


def design_args(task: str, out, *extra) -> list[str]:
    """`optix design TASK` at the smoke budget, one torch thread, quiet."""
    return ["design", task, "--out", str(out), "--budget", "smoke", "--threads", "1", "--quiet", *map(str, extra)]


@pytest.fixture(scope="session")
def smoke_design():
    """The arguments of a smoke `optix design` run: ``smoke_design(task, out, *extra)``."""
    return design_args


def _smoke_camera(task: str, precision: str = "fp32"):
    """A design run's camera at the smoke settings on the CPU (surrogate optics, the shipped
    processing), in training mode, and a seeded two-image batch with the camera's margin:
    (camera, scene [2, 3, 32 + 2m, 32 + 2m], target [2, 3, 32, 32])."""
    import torch

    from optix_e2e.camera_design.build import build_camera, load_surrogate
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.tasks import SensorFrame

    cfg = make_config(
        "smoke", surrogate="paper-triplet-v1", task=task, optics="surrogate", device="cpu", precision=precision
    )
    cam = build_camera(cfg, load_surrogate("paper-triplet-v1"), frame=SensorFrame()).train()
    m, g = cam.margin, torch.Generator().manual_seed(0)
    scene = torch.rand(2, 3, 32 + 2 * m, 32 + 2 * m, generator=g)
    return cam, scene, torch.rand(2, 3, 32, 32, generator=g)


@pytest.fixture(scope="session")
def smoke_camera():
    """``smoke_camera(task, precision="fp32")`` -> (camera, scene, target): see _smoke_camera."""
    return _smoke_camera


def _load_bench(name: str):
    """benches/NAME.py as a module (the benches are scripts, not a package), with benches/ on
    sys.path as when Python runs one: they import their siblings (``from alg1_vs_vanilla ...``)."""
    import sys

    benches = Path(__file__).resolve().parents[1] / "benches"
    if str(benches) not in sys.path:
        sys.path.insert(0, str(benches))
    path = benches / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def load_bench():
    """``load_bench("gpu")``: benches/gpu.py as a module."""
    return _load_bench


#: the longest test files, longest first (worker-seconds measured with ./test.sh on the 2-core
#: machine, 2026-11-27); used only to order them, so a stale entry costs time, never a result
LONGEST_FIRST = (
    "camera_design/test_distributed_training.py",
    "optics/test_optics_in_loop_runs.py",
    "camera_design/test_run_resume.py",
    "tasks/test_detector.py",
    "accuracy/test_auto.py",
    "optics/test_optics_in_loop.py",
    "camera_design/test_detection_run.py",
)


def pytest_collection_modifyitems(config, items):
    """The longest files first, then the other files with slow tests, then the rest: ./test.sh
    hands whole files to two workers in this order (pytest-xdist --dist loadfile), so the long
    ones start early instead of ending the run on one worker."""
    here = Path(__file__).resolve().parent
    rank = {here / f: i for i, f in enumerate(LONGEST_FIRST)}
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: (rank.get(item.path, len(rank)), item.path not in slow_files))
