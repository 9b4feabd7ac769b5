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


# -- no stage makes its tensors elsewhere than its inputs' device -------------------------------

#: torch functions that make a tensor from nothing (or from Python data): without ``device=`` they
#: make it on the CPU whatever device the stage's inputs are on
FACTORIES = {
    torch.zeros,
    torch.ones,
    torch.empty,
    torch.full,
    torch.arange,
    torch.linspace,
    torch.eye,
    torch.tensor,
    torch.as_tensor,
    torch.rand,
    torch.randn,
    torch.randint,
}
#: Tensor methods that bring data to the host: none belongs in a training step's forward or backward
TO_HOST = {torch.Tensor.cpu, torch.Tensor.numpy}
#: the sensor's constant tables (spectral interpolation, Eq. 3's photons per band, the QE curves):
#: made in float64 from the preset's numbers and moved to the signal's device and dtype at their
#: one use (sensor/emva.py expected_electrons), never mixed in on the CPU
CONSTANTS = {"interpolation_weights", "photons_per_radiance", "qe_curves"}


class DeviceSpy(torch.overrides.TorchFunctionMode):
    """Records every factory call that names no device (a 0-dim scalar and ``as_tensor`` of a
    tensor excepted: they mix with any device or keep their own) and every copy to the host."""

    def __init__(self):
        super().__init__()
        self.found: list[str] = []

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if func in FACTORIES and "device" not in kwargs:
            data = args[0] if args else kwargs.get("data")
            scalar = func in (torch.tensor, torch.as_tensor) and (
                isinstance(data, (int, float, bool)) or isinstance(data, torch.Tensor)
            )
            if not scalar and _where(name=True) not in CONSTANTS:
                self.found.append(f"{_where()}: torch.{func.__name__} names no device")
        if func in TO_HOST:
            self.found.append(f"{_where()}: Tensor.{func.__name__}() inside the step")
        return func(*args, **kwargs)


def _where(name: bool = False) -> str:
    """The package's innermost line on the stack (where a stage made the call), or its function's name."""
    import traceback

    ours = [f for f in traceback.extract_stack() if "optix_e2e" in f.filename]
    if not ours:
        return "?"
    return ours[-1].name if name else f"{ours[-1].filename.split('optix_e2e/')[-1]}:{ours[-1].lineno}"


@pytest.mark.parametrize("task", ["iq-software", "iq-hardware"])
def test_a_training_step_makes_every_tensor_on_its_inputs_device(task, smoke_camera):
    """A design run's training step (surrogate optics -> sensor with its seeded noise -> ISP ->
    L1 + LPIPS, forward and backward) under ``DeviceSpy``: every tensor it makes names its
    device (so on CUDA it is made there, not on the CPU) and nothing is copied to the host.

    Why not the meta device for the whole camera: the renderer and the sensor check their inputs
    (fields increasing, values finite), which reads data a meta tensor does not have; those
    stages run here on the CPU under the spy instead. Not covered: the Rust engine (exact optics:
    its values go to the CPU and its PSFs come back once per call, by design), the reference ISP
    (CPU by design), the detector's NMS and target assignment (torchvision's); the evaluation's
    batches are the next test's."""
    from optix_e2e.camera_design.training import noise_generator
    from optix_e2e.tasks import TaskLoss, get_task

    cam, scene, target = smoke_camera(task)
    loss_mod = TaskLoss(get_task(task))
    spy = DeviceSpy()
    with spy:
        out, _ = cam(scene, (120.0, -80.0), noise_generator(0, 0))
        loss, _ = loss_mod(out, target)
        loss.backward()
    assert not spy.found, "\n".join(dict.fromkeys(spy.found))
    assert cam.optics.u.grad is not None and bool(torch.isfinite(loss))


def test_an_evaluation_batch_makes_every_tensor_on_its_inputs_device(smoke_camera):
    """The held-out evaluation's camera output (``Camera.final_batch``: each sample's optics and
    common-random-number noise, whose Poisson quantile runs on the signal's device, then the ISP
    on the batch) and its metrics under ``DeviceSpy``: the uniforms come from each sample's CPU
    generator and move to the device (named), nothing else is made on or copied to the host."""
    from optix_e2e.metrics.image import haarpsi, psnr, ssim
    from optix_e2e.metrics.lpips import lpips

    cam, scene, target = smoke_camera("iq-software")
    scenes, targets = scene[:1].expand(2, -1, -1, -1), target[:1].expand(2, -1, -1, -1)
    lpips(targets, targets)  # LPIPS's network is built once (on the CPU) and moved: not per call
    spy = DeviceSpy()
    with spy, torch.no_grad():
        out = cam.final_batch(scenes, [(120.0, -80.0), (0.0, 0.0)], [torch.Generator().manual_seed(k) for k in (1, 2)])
        x = (out.clamp(0, 1) * 255).round() / 255
        for metric in (psnr, ssim, lpips, haarpsi):
            metric(x, targets)
    assert not spy.found, "\n".join(dict.fromkeys(spy.found))
    assert out.shape[0] == 2 and not torch.equal(out[0], out[1])


def test_the_spy_catches_a_stage_that_makes_a_tensor_on_the_cpu(monkeypatch, smoke_camera):
    """The test above can fail: a stage that makes a device-less tensor or copies to the host is caught."""
    from optix_e2e.camera import stages

    cam, scene, _ = smoke_camera("iq-hardware")
    for plant in (lambda raw: raw + torch.zeros(raw.shape), lambda raw: raw.cpu()):
        forward = stages.HardwareISPStage.forward
        monkeypatch.setattr(
            stages.HardwareISPStage, "forward", lambda self, raw, *a, p=plant, f=forward: f(self, p(raw))
        )
        spy = DeviceSpy()
        with spy:
            cam(scene, (0.0, 0.0), torch.Generator().manual_seed(0))
        assert spy.found, "the spy missed a planted CPU tensor"
        monkeypatch.undo()


def test_the_networks_and_metrics_run_on_the_meta_device(smoke_camera):
    """The ISP stages (software ISP, the hardware ISP's proxy at its hyperparameters), LPIPS and the
    detector's backbone on the meta device with meta inputs: an op that mixed in a CPU tensor (not a
    0-dim scalar) or copied to the host would raise, so their outputs on meta mean nothing inside
    them lives elsewhere."""
    from optix_e2e.metrics.lpips import LPIPS
    from optix_e2e.tasks.detector import TinyBackbone

    meta = torch.device("meta")
    for task in ("iq-software", "iq-hardware"):
        isp = smoke_camera(task)[0].isp.to(meta)
        out = isp(torch.rand(2, 1, 32, 32, device=meta), (120.0, -80.0), 1100.0)
        assert out.device == meta and out.shape == (2, 3, 32, 32)
    x = torch.rand(2, 3, 32, 32, device=meta)
    assert LPIPS().to(meta)(x, x).device == meta
    feats = TinyBackbone(16, 32).to(meta)(torch.rand(1, 3, 64, 96, device=meta))
    assert all(f.device == meta for f in feats.values())
