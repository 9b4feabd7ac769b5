"""``--precision``: the networks under autocast, the optics, sensor and losses in float32 (issue 36).

What the switch says it does, checked on the CPU (bf16 autocast runs there): with bf16 the ISP's
and the detector's convolutions compute in bfloat16 inside, and every tensor the optics, the
sensor, the renderer and the losses make stays float32; with fp32 nothing anywhere is bfloat16."""

from __future__ import annotations

import json

import pytest
import torch

from optix_e2e.errors import InputError
from optix_e2e.precision import apply_precision, grad_scaler, resolve_precision

#: the package's files whose torch calls may compute in the low precision: the networks
NETWORK_FILES = ("isp/unet.py", "isp/nafnet.py", "isp/rawnet.py", "isp/software.py", "tasks/detector.py")


class DtypeSpy(torch.overrides.TorchFunctionMode):
    """Records where (the package's innermost file on the stack) each torch call returned a
    tensor of a low precision, and every tensor's dtype a call from ``watch`` returned."""

    def __init__(self):
        super().__init__()
        self.low: dict[str, int] = {}

    def __torch_function__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for t in out if isinstance(out, (tuple, list)) else (out,):
            if isinstance(t, torch.Tensor) and t.dtype in (torch.bfloat16, torch.float16):
                where = _where()
                self.low[where] = self.low.get(where, 0) + 1
        return out


def _where() -> str:
    import traceback

    ours = [f for f in traceback.extract_stack() if "optix_e2e" in f.filename]
    return ours[-1].filename.split("optix_e2e/")[-1] if ours else "?"


def test_the_names_and_what_a_device_cannot_do():
    assert resolve_precision("fp32", "cpu") is None
    assert resolve_precision("bf16", "cpu") is torch.bfloat16
    for bad in ("bf32", "FP16", "", None, 16):
        with pytest.raises(InputError, match="--precision must be fp32, bf16 or fp16"):
            resolve_precision(bad, "cpu")


def test_a_device_without_the_dtype_is_one_clear_error(monkeypatch):
    from optix_e2e import precision

    monkeypatch.setattr(precision, "_autocasts", lambda device, dtype: False)
    with pytest.raises(InputError, match=r"^precision fp16: torch .* cannot autocast to torch.float16 on cpu"):
        resolve_precision("fp16", "cpu", option="precision")
    monkeypatch.setattr(torch.amp, "is_autocast_available", lambda kind: False)
    with pytest.raises(InputError, match="--precision bf16: torch has no autocast on cpu; use --precision fp32"):
        resolve_precision("bf16", "cpu")


@pytest.mark.parametrize("task", ["iq-software", "iq-hardware"])
def test_bf16_reaches_the_isp_network_only(task, smoke_camera):
    """A design run's training step (surrogate optics, sensor with noise, ISP, L1 + LPIPS,
    backward) with --precision bf16: bfloat16 tensors appear inside the ISP's network and
    nowhere else; each stage's output is float32; with fp32, no bfloat16 anywhere."""
    from optix_e2e.camera_design.training import noise_generator
    from optix_e2e.tasks import TaskLoss, get_task

    low_where = {}
    for precision in ("bf16", "fp32"):
        torch.manual_seed(0)
        cam, scene, target = smoke_camera(task, precision)
        loss_mod = TaskLoss(get_task(task))
        m = cam.margin
        spy = DtypeSpy()
        with spy:
            psf, vig = cam.optics.psfs()
            image = cam.optics(scene, (120.0, -80.0))[..., m:-m, m:-m]
            raw = cam.sensor(image, noise_generator(0, 0))
            out = cam.isp(raw, (120.0, -80.0), cam.optics.full_field_px)
            loss, _ = loss_mod(out, target)
        loss.backward()
        for name, t in (("psf", psf), ("vignetting", vig), ("render", image), ("raw", raw), ("isp", out)):
            assert t.dtype == torch.float32, (precision, name, t.dtype)
        assert loss.dtype == torch.float32 and bool(torch.isfinite(loss))
        low_where[precision] = spy.low
    assert low_where["fp32"] == {}, low_where["fp32"]
    assert low_where["bf16"], "bf16 reached no network"
    assert set(low_where["bf16"]) <= set(NETWORK_FILES), low_where["bf16"]


def test_bf16_detector_computes_low_inside_and_its_losses_in_float32():
    from optix_e2e.tasks.detector import make_detector

    torch.manual_seed(0)
    model = make_detector(8, 32, (64, 96)).train()
    assert sorted(apply_precision(model, torch.bfloat16)) == ["backbone", "head"]
    xs = [torch.rand(3, 64, 96)]
    ts = [{"boxes": torch.tensor([[10.0, 10.0, 40.0, 40.0]]), "labels": torch.tensor([1])}]
    spy = DtypeSpy()
    with spy:
        losses = model(xs, ts)
    assert set(spy.low) == {"tasks/detector.py"}, spy.low
    assert all(v.dtype == torch.float32 and torch.isfinite(v) for v in losses.values()), losses
    sum(losses.values()).backward()
    apply_precision(model, None)
    spy = DtypeSpy()
    with spy:
        model(xs, ts)
    assert spy.low == {}


def test_the_precision_switch_leaves_the_weights_and_the_fp32_output_alone(smoke_camera):
    """The switch is no state: the state dict is the same with it set, and the fp32 output is
    the same as a camera built before the switch is touched."""
    a, b = smoke_camera("iq-software", "fp32")[0], smoke_camera("iq-software", "bf16")[0]
    sa, sb = a.state_dict(), b.state_dict()
    assert list(sa) == list(sb) and all(torch.equal(sa[k], sb[k]) for k in sa)
    raw = 800.0 + 200.0 * torch.rand(1, 1, 32, 32, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        fp32 = a.isp(raw, (0.0, 0.0), a.optics.full_field_px)
        bf16 = b.isp(raw, (0.0, 0.0), a.optics.full_field_px)
        apply_precision(b, None)
        back = b.isp(raw, (0.0, 0.0), a.optics.full_field_px)
    assert torch.equal(fp32, back)
    assert not torch.equal(fp32, bf16) and (fp32 - bf16).abs().max() < 0.05  # bf16 rounds, a little


def test_fp16_steps_through_a_gradient_scaler_and_keeps_its_state(smoke_camera):
    """fp16 (here on the CPU, where this torch autocasts it): Alg. 1's step scales the loss,
    unscales before the step and saves the scaler's state with the optimizer's."""
    from optix_e2e.camera_design.build import make_optimizer
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.tasks import TaskLoss, get_task

    try:
        resolve_precision("fp16", "cpu")
    except InputError:
        pytest.skip("this torch has no fp16 autocast on the CPU")
    cfg = make_config("smoke", surrogate="paper-triplet-v1", task="iq-hardware", optics="surrogate", precision="fp16")
    cam, scene, _ = smoke_camera("iq-hardware", "fp16")
    opt = make_optimizer(cfg, cam, "alg1")
    assert isinstance(opt.scaler, torch.amp.GradScaler) and grad_scaler("cpu", None) is None
    loss_mod = TaskLoss(get_task("iq-hardware"))
    m = cam.margin
    before = cam.optics.u.detach().clone()
    info = opt.step(
        lambda: loss_mod(cam(scene, (0.0, 0.0), torch.Generator().manual_seed(0))[0], scene[..., m:-m, m:-m])
    )
    assert info["loss"] > 0 and opt.t == 1
    assert not torch.equal(before, cam.optics.u.detach())  # the first block (optics) stepped, unscaled
    st = opt.state_dict()
    assert st["scaler"]["scale"] == opt.scaler.get_scale()
    assert "scaler" not in make_optimizer(make_config("smoke", task="iq-hardware"), cam, "alg1").state_dict()


def test_a_config_file_names_itself_in_a_device_or_precision_error(tmp_path, monkeypatch):
    from optix_e2e.camera_design.config import make_config

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    f = tmp_path / "run.toml"
    f.write_text('precision = "bf16"\n')
    assert make_config("smoke", f, device="cpu").precision == "bf16"
    assert make_config("smoke").precision == "fp32"  # the default: no autocast anywhere
    f.write_text('device = "cuda"\n')
    with pytest.raises(InputError, match=rf"^{f}: device cuda: this machine has no CUDA device"):
        make_config("smoke", f)
    f.write_text('precision = "fp64"\n')
    with pytest.raises(InputError, match=rf"^{f}: precision must be fp32, bf16 or fp16, got 'fp64'"):
        make_config("smoke", f)


def test_detect_train_records_its_precision(tmp_path):
    from optix_e2e.scenes.coco import write_street_coco
    from optix_e2e.tasks.detector_train import train_detector

    write_street_coco(tmp_path / "street", 2, seed=0, size=(64, 96))
    res = train_detector(
        tmp_path / "street", tmp_path / "det", steps=1, batch=2, precision="bf16", progress=False, log=lambda m: None
    )
    assert res["precision"] == "bf16" and res["steps"] == 1
    assert torch.load(tmp_path / "det" / "detector.pt", weights_only=True)["precision"] == "bf16"
    with pytest.raises(InputError, match="--precision must be"):
        train_detector(tmp_path / "street", tmp_path / "det2", steps=1, precision="tf32", progress=False)
    assert not (tmp_path / "det2").exists()


@pytest.mark.slow
def test_every_network_training_takes_precision_and_records_it(optix, tmp_path):
    """``--precision bf16`` on the commands that train a network through the switch, in their
    smallest forms (the design run at the smoke budget: its results.json)."""
    runs = {
        "proxy": [
            *("isp", "train-proxy", "--out", tmp_path / "proxy", "--steps", "2", "--batch", "2", "--patch", "32"),
            *("--pool", "16", "--base", "4", "--json"),
        ],
        "sw": [
            *("isp", "train-software", "--out", tmp_path / "sw", "--steps", "2", "--batch", "1", "--crop", "32"),
            *("--pool", "8", "--width", "4", "--depth", "1", "--val-every", "2", "--json"),
        ],
        "design": [
            *("design", "iq-hardware", "--out", tmp_path / "design", "--budget", "smoke", "--threads", "1"),
            "--quiet",
        ],
    }
    for name, args in runs.items():
        r = optix(*args, "--device", "cpu", "--precision", "bf16")
        assert r.returncode == 0, f"{name}: {r.stdout}{r.stderr}"
    assert json.loads((tmp_path / "proxy" / "train.json").read_text())["precision"] == "bf16"
    assert json.loads((tmp_path / "sw" / "train.json").read_text())["precision"] == "bf16"
    results = json.loads((tmp_path / "design" / "results.json").read_text())
    assert results["precision"] == "bf16" and results["device"] == "cpu"
    # the run is held to its precision: asked for fp32, the folder is another run's; not asked,
    # the run resumes in its own (a finished run: nothing trained again)
    r = optix(*runs["design"], "--device", "cpu", "--precision", "fp32")
    assert r.returncode == 1 and "precision: 'bf16' -> 'fp32'" in r.stderr, r.stderr
    r = optix(*runs["design"], "--device", "cpu")
    assert r.returncode == 0 and "resumes with its own precision = 'bf16'" in r.stdout, r.stdout + r.stderr
