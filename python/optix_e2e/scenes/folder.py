"""A torch Dataset over a folder of the user's own images."""

from __future__ import annotations

from pathlib import Path

import torch
from torch.utils.data import Dataset

from ..errors import InputError
from .photos import fit_size, to_image_tensor

__all__ = ["ImageFolder"]

DEFAULT_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


class ImageFolder(Dataset):
    """Images under ``root`` as float32 sRGB tensors [3,H,W] in [0,1], in sorted path order.

    8-bit and 16-bit files are scaled by 255 / 65535; greyscale is repeated to 3 channels and
    alpha is dropped.  Multi-frame files give their first frame.  Note that Pillow (imageio's
    PNG reader) reads 16-bit *colour* PNGs at 8-bit precision; 16-bit greyscale PNGs and
    16-bit TIFFs keep full precision.  With ``size`` (int or (h, w)) every image is
    centre-cropped to that aspect ratio and resized, so batches stack.

    Raises FileNotFoundError if ``root`` does not exist, NotADirectoryError if it is a file,
    ValueError if it holds no image with one of ``extensions`` (case-insensitive), and, from
    ``dataset[i]``, ValueError naming the file if an image cannot be decoded.
    """

    def __init__(
        self,
        root: str | Path,
        size: int | tuple[int, int] | None = None,
        extensions: tuple[str, ...] = DEFAULT_EXTENSIONS,
        recursive: bool = True,
    ):
        self.root = Path(root)
        if not self.root.exists():
            raise FileNotFoundError(f"image folder not found: {self.root}")
        if not self.root.is_dir():
            raise NotADirectoryError(f"not a folder: {self.root}")
        exts = {e.lower() if e.startswith(".") else "." + e.lower() for e in extensions}
        pattern = "**/*" if recursive else "*"
        self.paths = sorted(p for p in self.root.glob(pattern) if p.is_file() and p.suffix.lower() in exts)
        if not self.paths:
            raise InputError(
                f"no images ({', '.join(sorted(exts))}) found in {self.root}"
                + (" or its subfolders" if recursive else "")
            )
        self.size = size

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index: int) -> torch.Tensor:
        import imageio.v3 as iio

        path = self.paths[index]
        try:
            array = iio.imread(path, index=0)
            while array.ndim > 3:  # a stack stored as one series: take its first frame
                array = array[0]
            img = to_image_tensor(array)
        except Exception as err:  # imageio raises OSError, ValueError, SyntaxError, ... per plugin
            raise InputError(f"cannot read image {path}: {err}") from err
        return fit_size(img, self.size)
