"""Mixed precision where it is safe (issue 36): the networks under autocast, the physics in float32.

``--precision fp32`` (the default) runs everything in float32, as before the switch existed.
``bf16`` and ``fp16`` run the *networks* under ``torch.autocast`` at that dtype: the software
ISP's learned correction (isp/software.py, its UNet body; the classical pipeline in front of it
stays float32), the hardware ISP's proxy (isp/proxy.py) and the detector's backbone and head
(tasks/detector.py). Each network's output is cast back to float32 where it leaves the network,
so what follows it is float32 as before: the optics (the surrogate's PSFs, the renderer), the
sensor's statistics (photon counts, Poisson and read noise, quantisation), the losses (L1, LPIPS,
the detector's focal, GIoU and centre-ness losses) and every metric. The optics surrogate is a
network too but stays float32: its PSFs are the optics.

A network opts in by having an ``autocast_dtype`` attribute (None: float32) that its forward
reads (:func:`network_autocast`); :func:`apply_precision` sets it on every such module under a
model. fp16 needs a gradient scaler (:func:`grad_scaler`); bf16 does not.
"""

from __future__ import annotations

import contextlib

import torch

from .errors import InputError

PRECISIONS = {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}
FORMS = "fp32, bf16 or fp16"


def resolve_precision(spec: str, device: "torch.device | str", *, option: str = "--precision") -> torch.dtype | None:
    """The autocast dtype ``spec`` names on ``device`` (None: fp32, no autocast); one error naming
    ``option`` where the name is unknown or the device cannot run that dtype under autocast."""
    if not isinstance(spec, str) or spec not in PRECISIONS:
        raise InputError(f"{option} must be {FORMS}, got {spec!r}")
    dtype = PRECISIONS[spec]
    if dtype is None:
        return None
    device = torch.device(device)
    if device.type == "meta":
        return dtype
    if not torch.amp.is_autocast_available(device.type):
        raise InputError(f"{option} {spec}: torch has no autocast on {device.type}; use {option} fp32")
    if device.type == "cuda" and dtype is torch.bfloat16 and not torch.cuda.is_bf16_supported():
        raise InputError(f"{option} bf16: {torch.cuda.get_device_name(device)} cannot compute in bfloat16; use fp16")
    if not _autocasts(device, dtype):
        raise InputError(f"{option} {spec}: torch {torch.__version__} cannot autocast to {dtype} on {device.type}")
    return dtype


_PROBED: dict = {}


def _autocasts(device: torch.device, dtype: torch.dtype) -> bool:
    """Whether a convolution under autocast at ``dtype`` on ``device`` runs and gives ``dtype``
    (older torch refuses fp16 on the CPU, or ignores it with a warning)."""
    key = (device.type, dtype)
    if key not in _PROBED:
        try:
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                x = torch.ones(1, 1, 3, 3, device=device)
                with torch.autocast(device.type, dtype=dtype):
                    y = torch.nn.functional.conv2d(x, torch.ones(1, 1, 1, 1, device=device))
            _PROBED[key] = y.dtype == dtype
        except (RuntimeError, TypeError, ValueError):
            _PROBED[key] = False
    return _PROBED[key]


def network_autocast(x: torch.Tensor, dtype: torch.dtype | None):
    """The context a network's forward runs in: autocast at ``dtype`` on ``x``'s device, or
    nothing (float32, the code path of before the switch) where ``dtype`` is None."""
    if dtype is None:
        return contextlib.nullcontext()
    return torch.autocast(x.device.type, dtype=dtype)


def to_float32(out):
    """A network's output back in float32 (tensors, and tensors in dicts, lists and tuples)."""
    if isinstance(out, torch.Tensor):
        return out.float() if out.is_floating_point() and out.dtype != torch.float32 else out
    if isinstance(out, dict):
        return type(out)((k, to_float32(v)) for k, v in out.items())
    if isinstance(out, (list, tuple)):
        return type(out)(to_float32(v) for v in out)
    return out


def apply_precision(model: torch.nn.Module, dtype: torch.dtype | None) -> list[str]:
    """Set ``autocast_dtype`` on every network under ``model`` that has the switch; returns
    their names (the modules the switch reaches)."""
    found = []
    for name, m in model.named_modules():
        if hasattr(m, "autocast_dtype"):
            m.autocast_dtype = dtype
            found.append(name)
    return found


def grad_scaler(device: "torch.device | str", dtype: torch.dtype | None):
    """fp16's loss scaler on ``device`` (None for fp32 and bf16, which need none)."""
    if dtype is not torch.float16:
        return None
    return torch.amp.GradScaler(torch.device(device).type)


def scaled_backward(loss: torch.Tensor, opt: torch.optim.Optimizer, scaler) -> None:
    """``loss.backward()``, through fp16's scaler where there is one; the gradients come out
    unscaled either way (ready to clip)."""
    if scaler is None:
        loss.backward()
        return
    scaler.scale(loss).backward()
    scaler.unscale_(opt)


def scaled_step(opt: torch.optim.Optimizer, scaler) -> None:
    """``opt.step()``, through fp16's scaler where there is one (a step whose gradients
    overflowed is skipped, and the scale lowered)."""
    if scaler is None:
        opt.step()
        return
    scaler.step(opt)
    scaler.update()


def name(dtype: torch.dtype | None) -> str:
    """The precision's name (results.json) for an autocast dtype."""
    return {v: k for k, v in PRECISIONS.items()}[dtype]
