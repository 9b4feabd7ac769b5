"""``--device``: one reading of the option for every command (optix_e2e.device, issue 36)."""

from __future__ import annotations

import pytest
import torch

from optix_e2e import parallel
from optix_e2e.device import resolve_device
from optix_e2e.errors import InputError


def _gpus(monkeypatch, n: int) -> None:
    """Pretend torch sees ``n`` CUDA devices (none: no CUDA at all)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: n > 0)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: n)


def test_auto_is_cuda_when_present_else_cpu(monkeypatch):
    _gpus(monkeypatch, 0)
    assert resolve_device("auto") == torch.device("cpu")
    _gpus(monkeypatch, 2)
    assert resolve_device("auto") == torch.device("cuda", 0)
    assert resolve_device("auto", local_rank=1) == torch.device("cuda", 1)  # torchrun: the process's own GPU


def test_cpu_and_cuda_forms(monkeypatch):
    _gpus(monkeypatch, 2)
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("cuda") == torch.device("cuda", 0)
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    assert resolve_device("cuda", local_rank=1) == torch.device("cuda", 1)


def test_a_gpu_that_is_not_there_is_one_clear_error(monkeypatch):
    _gpus(monkeypatch, 0)
    for spec in ("cuda", "cuda:0"):
        with pytest.raises(InputError, match=rf"--device {spec}: this machine has no CUDA device.*--device cpu"):
            resolve_device(spec)
    _gpus(monkeypatch, 2)
    with pytest.raises(InputError, match=r"--device cuda:2: this machine has 2 CUDA devices \(cuda:0 \.\. cuda:1\)"):
        resolve_device("cuda:2")
    _gpus(monkeypatch, 1)
    with pytest.raises(InputError, match=r"--device cuda:5: this machine has 1 CUDA device \(cuda:0\)"):
        resolve_device("cuda:5")


@pytest.mark.parametrize("spec", ["gpu", "CUDA", "cuda:", "cuda:-1", "cuda:x", "cpu:0", "meta", "", " cpu", 0, None])
def test_anything_else_lists_the_accepted_forms(spec, monkeypatch):
    _gpus(monkeypatch, 1)
    with pytest.raises(InputError, match="auto, cpu, cuda or cuda:K"):
        resolve_device(spec)


def test_the_option_name_is_the_callers(monkeypatch):
    _gpus(monkeypatch, 0)
    with pytest.raises(InputError, match="^config.toml: device cuda: "):
        resolve_device("cuda", option="config.toml: device")


def test_parallel_setup_resolves_through_it(monkeypatch):
    """The surrogate's training (and torchrun's ranks) read --device the same way."""
    _gpus(monkeypatch, 0)
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    assert parallel.setup("cpu").device == torch.device("cpu")
    assert parallel.setup("auto").device == torch.device("cpu")
    with pytest.raises(InputError, match="--device cuda: this machine has no CUDA device"):
        parallel.setup("cuda")
