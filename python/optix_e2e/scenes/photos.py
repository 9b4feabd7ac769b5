"""Colour photographs that ship inside installed packages (no network, ever).

scikit-image's wheel carries a handful of photographs as plain files in ``skimage/data``.
They are read here straight from that folder with imageio; ``skimage.data``'s loader
functions are not used, because some of them fetch files with pooch.  The list is curated:
greyscale files (camera, moon, ...), synthetic graphics (color.png, logo.png,
chessboard_RGB.png) and multi-page files are left out.  Licences: see skimage/data/README.txt.

Also holds the numpy -> tensor conversion and the centre-crop/resize shared with the folder
loader.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import InputError

__all__ = ["bundled_photos", "load_photo", "to_image_tensor", "fit_size"]

# name -> file in skimage/data.  All are 8-bit RGB photographs.
_PHOTO_FILES = {
    "astronaut": "astronaut.png",  # portrait, NASA
    "chelsea": "chelsea.png",  # cat, fur texture
    "coffee": "coffee.png",  # saturated colours, specular highlights
    "rocket": "rocket.jpg",  # outdoor scene, sky, vehicle
    "motorcycle_left": "motorcycle_left.png",  # Middlebury stereo pair, fine detail
    "motorcycle_right": "motorcycle_right.png",
    "hubble_deep_field": "hubble_deep_field.jpg",  # point sources on black
    "retina": "retina.jpg",  # fundus photograph, red/orange
    "ihc": "ihc.png",  # stained tissue micrograph
}


def _data_dir() -> Path | None:
    try:
        import skimage
    except ImportError:  # pragma: no cover - scikit-image is a dependency
        return None
    return Path(skimage.__file__).parent / "data"


def _photo_path(name: str) -> Path | None:
    folder = _data_dir()
    path = folder / _PHOTO_FILES[name] if folder is not None else None
    return path if path is not None and path.is_file() else None


def bundled_photos() -> list[str]:
    """Names of the colour photos available offline in this installation, sorted."""
    return sorted(n for n in _PHOTO_FILES if _photo_path(n) is not None)


def to_image_tensor(array: np.ndarray) -> torch.Tensor:
    """An imageio array (H,W), (H,W,1..4) of uint8/uint16/float/bool -> float32 [3,H,W] in [0,1].

    Greyscale is repeated to 3 channels; alpha (grey+A or RGBA) is dropped, not composited.
    Floats are clipped to [0,1].
    """
    a = np.asarray(array)
    if a.dtype == np.uint8:
        a = a.astype(np.float32) / 255.0
    elif a.dtype == np.uint16:
        a = a.astype(np.float32) / 65535.0
    elif a.dtype == np.bool_ or np.issubdtype(a.dtype, np.floating):
        a = np.clip(a.astype(np.float32), 0.0, 1.0)
    else:
        raise InputError(f"unsupported image dtype {a.dtype} (expected uint8, uint16 or float)")
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4):
        raise InputError(f"unsupported image shape {array.shape} (expected HxW or HxWxC, C<=4)")
    a = a[:, :, :1].repeat(3, axis=2) if a.shape[2] <= 2 else a[:, :, :3]
    return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))


def fit_size(img: torch.Tensor, size: int | tuple[int, int] | None) -> torch.Tensor:
    """Centre-crop ``img`` [C,H,W] to the aspect ratio of ``size`` and resize to it.

    ``size`` is an int (square) or (h, w); None returns ``img`` unchanged.  Resizing is
    bilinear with antialiasing, so downscaling does not alias.
    """
    if size is None:
        return img
    th, tw = (size, size) if isinstance(size, int) else (int(size[0]), int(size[1]))
    if th < 1 or tw < 1:
        raise InputError(f"size must be positive, got {size}")
    _, h, w = img.shape
    ch, cw = (h, round(h * tw / th)) if h * tw <= w * th else (round(w * th / tw), w)
    ch, cw = min(max(ch, 1), h), min(max(cw, 1), w)
    y0, x0 = (h - ch) // 2, (w - cw) // 2
    img = img[:, y0 : y0 + ch, x0 : x0 + cw]
    if (ch, cw) != (th, tw):
        img = F.interpolate(img[None], size=(th, tw), mode="bilinear", align_corners=False, antialias=True)[0].clamp(
            0.0, 1.0
        )
    return img.contiguous()


def load_photo(name: str, size: int | tuple[int, int] | None = None) -> torch.Tensor:
    """Load a bundled photo as float32 sRGB [3,H,W] in [0,1]; see :func:`fit_size` for ``size``."""
    if name not in _PHOTO_FILES:
        raise InputError(f"unknown photo {name!r}; known photos: {', '.join(bundled_photos())}")
    path = _photo_path(name)
    if path is None:
        raise FileNotFoundError(
            f"photo {name!r} ({_PHOTO_FILES[name]}) is not in this scikit-image installation ({_data_dir()})"
        )
    import imageio.v3 as iio

    return fit_size(to_image_tensor(iio.imread(path)), size)
