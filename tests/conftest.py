"""Shared fixtures: the bundled Cooke triplet and the reference data in ../shared/reference.

The reference folder is looked up as <repo root>/../shared/reference (CI clones the repo
with shared/ beside it) unless OPTIX_REFERENCE_DIR points elsewhere.  A missing folder is
a test failure with a message, never a silent skip.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def reference_dir() -> Path:
    env = os.environ.get("OPTIX_REFERENCE_DIR")
    return Path(env) if env else REPO_ROOT.parent / "shared" / "reference"


@pytest.fixture(scope="session")
def ref_dir() -> Path:
    path = reference_dir()
    if not (path / "cooke_triplet_reference.json").is_file():
        pytest.fail(
            f"reference data not found at {path}: clone the repository with shared/ beside it "
            f"(../shared/reference) or set OPTIX_REFERENCE_DIR",
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


def pytest_collection_modifyitems(config, items):
    """Files with slow tests first: ./test.sh hands whole files to two workers in this order
    (pytest-xdist --dist loadfile), so the long ones start early instead of ending the run."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow_files)
