"""Detection data in COCO format: write the street scenes as a COCO set, and read a user's
real data (an image folder + a COCO annotation file) with one clear error per problem.

COCO boxes are ``[x, y, width, height]`` in pixels from the image's top-left corner; in
torch the targets are ``boxes`` [N, 4] as x0, y0, x1, y1 (torchvision's convention) and
``labels`` [N], the category ids as the file gives them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..io import save_image, write_text_atomic
from .street import CATEGORIES, street_scene


class CocoFormatError(InputError):
    """A COCO file or image folder that cannot be used as it is; the message names the file
    and the image or annotation."""


def write_street_coco(out: "str | Path", n: int, size=(256, 384), seed: int = 0, progress: bool = False) -> Path:
    """``n`` street scenes as 8-bit sRGB PNGs in ``out/images`` and ``out/annotations.json``
    (scene ``i`` is ``street_scene(size, [seed, i])``, so any scene can be made again alone).
    Extra per-object key: ``illumination`` (mean light over its visible pixels, sunlit = 1)."""
    from tqdm import tqdm

    from ..color import linear_to_srgb

    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(
            f"{out} is not an empty folder; a street set is written whole into a new or empty "
            f"--out (nothing there is replaced)"
        )
    (out / "images").mkdir(parents=True, exist_ok=True)
    images, anns = [], []
    for i in tqdm(range(n), desc="street scenes", unit="scene", disable=not progress):
        s = street_scene(size, np.random.default_rng([int(seed), i]))
        name = f"street_{seed}_{i:06d}.png"
        srgb = linear_to_srgb(s.radiance.clamp(0, 1)).permute(1, 2, 0).numpy()
        save_image(out / "images" / name, (srgb * 255 + 0.5).astype(np.uint8))
        h, w = s.radiance.shape[-2:]
        images.append({"id": i + 1, "file_name": name, "height": int(h), "width": int(w)})
        for (x0, y0, x1, y1), c, light in zip(s.boxes.tolist(), s.labels.tolist(), s.object_light.tolist()):
            anns.append(
                {
                    "id": len(anns) + 1,
                    "image_id": i + 1,
                    "category_id": int(c),
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "area": (x1 - x0) * (y1 - y0),
                    "iscrowd": 0,
                    "illumination": light,
                }
            )
    ann_path = out / "annotations.json"
    write_text_atomic(
        ann_path,
        json.dumps(
            {
                "info": {"description": f"optix-e2e street scenes, seed {seed}", "size": list(size)},
                "images": images,
                "annotations": anns,
                "categories": list(CATEGORIES),
            }
        ),
    )
    return ann_path


def _need(obj, key, kind, where):
    if not isinstance(obj, dict) or key not in obj:
        raise CocoFormatError(f"{where}: missing '{key}'")
    v = obj[key]
    ok = isinstance(v, kind) and not isinstance(v, bool)
    if not ok:
        raise CocoFormatError(f"{where}: '{key}' must be {getattr(kind, '__name__', kind)}, got {v!r}")
    return v


class CocoDetection(torch.utils.data.Dataset):
    """A COCO detection set: ``image_dir`` with the images, ``ann_file`` naming them.

    Everything is checked when it is opened, so a bad file fails at once with one line:
    unreadable or invalid JSON (with line and column), missing or mistyped keys, duplicate
    ids, an annotation naming an unknown image or category, a box that is not four finite
    numbers with positive width and height inside its image (1 px tolerance), a missing image
    file. ``ds[i]`` is (image [3, H, W] float sRGB in [0, 1], {"boxes", "labels", "image_id"});
    an image whose size differs from the file's record is an error naming it. Crowd
    annotations (``iscrowd`` 1) are left out of the targets. ``images[i]["illumination"]``
    keeps each target's ``illumination`` (the street scenes' extra key; None where absent).
    """

    def __init__(self, image_dir: "str | Path", ann_file: "str | Path"):
        self.image_dir, self.ann_file = Path(image_dir), Path(ann_file)
        try:
            data = json.loads(self.ann_file.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise CocoFormatError(f"{self.ann_file}: annotation file not found") from None
        except UnicodeDecodeError as err:
            raise CocoFormatError(f"{self.ann_file}: not UTF-8 text ({err.reason} at byte {err.start})") from None
        except json.JSONDecodeError as err:
            raise CocoFormatError(
                f"{self.ann_file}: invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}"
            ) from None
        except OSError as err:
            raise CocoFormatError(f"{self.ann_file}: cannot read ({err.strerror})") from None
        except RecursionError:
            raise CocoFormatError(f"{self.ann_file}: invalid JSON: nested too deeply to be a COCO file") from None
        f = str(self.ann_file)
        if not isinstance(data, dict):
            raise CocoFormatError(f"{f}: the top level must be an object with images, annotations, categories")
        images, anns, cats = (_need(data, k, list, f) for k in ("images", "annotations", "categories"))
        self.categories = {}
        for k, c in enumerate(cats):
            cid = _need(c, "id", int, f"{f}: categories[{k}]")
            if cid in self.categories:
                raise CocoFormatError(f"{f}: categories[{k}]: duplicate category id {cid}")
            self.categories[cid] = str(_need(c, "name", str, f"{f}: categories[{k}]"))
        self.images, index = [], {}
        for k, im in enumerate(images):
            where = f"{f}: images[{k}]"
            iid = _need(im, "id", int, where)
            name = _need(im, "file_name", str, where)
            h, w = _need(im, "height", int, where), _need(im, "width", int, where)
            if iid in index:
                raise CocoFormatError(f"{where}: duplicate image id {iid}")
            if h < 1 or w < 1:
                raise CocoFormatError(f"{where} ({name}): height and width must be positive, got {h} x {w}")
            # a file name is a path inside image_dir: no absolute path, no way out by ".." (links
            # that the folder's owner put there are followed: shared stores, git-annex)
            if "\x00" in name or Path(name).is_absolute() or ".." in Path(name).parts:
                raise CocoFormatError(f"{where}: file_name {name!r} leaves the image folder {self.image_dir}")
            if not (self.image_dir / name).is_file():
                raise CocoFormatError(f"{where}: image file {self.image_dir / name} not found")
            index[iid] = len(self.images)
            self.images.append(
                {"id": iid, "file_name": name, "height": h, "width": w, "boxes": [], "labels": [], "illumination": []}
            )
        seen = set()
        for k, a in enumerate(anns):
            where = f"{f}: annotations[{k}]"
            aid = _need(a, "id", int, where)
            where = f"{f}: annotation id {aid}"
            if aid in seen:
                raise CocoFormatError(f"{where}: duplicate annotation id")
            seen.add(aid)
            iid, cid = _need(a, "image_id", int, where), _need(a, "category_id", int, where)
            if iid not in index:
                raise CocoFormatError(f"{where}: image_id {iid} is not among the images")
            if cid not in self.categories:
                raise CocoFormatError(
                    f"{where}: category_id {cid} is not among the categories "
                    f"({', '.join(map(str, sorted(self.categories)))})"
                )
            box = a.get("bbox")
            im = self.images[index[iid]]
            if (
                not isinstance(box, list)
                or len(box) != 4
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in box)
            ):
                raise CocoFormatError(f"{where}: bbox must be four finite numbers [x, y, width, height], got {box!r}")
            x, y, bw, bh = map(float, box)
            if bw <= 0 or bh <= 0:
                raise CocoFormatError(f"{where}: bbox {box} has no area")
            if x < -1 or y < -1 or x + bw > im["width"] + 1 or y + bh > im["height"] + 1:
                raise CocoFormatError(
                    f"{where}: bbox {box} lies outside its image {im['file_name']} ({im['width']} x {im['height']})"
                )
            if a.get("iscrowd", 0):
                continue
            im["boxes"].append([x, y, x + bw, y + bh])
            im["labels"].append(cid)
            light = a.get("illumination")  # our scenes' extra key; None where a file lacks it
            if light is not None and (
                isinstance(light, bool) or not isinstance(light, (int, float)) or not math.isfinite(light) or light < 0
            ):
                raise CocoFormatError(f"{where}: illumination must be a finite number >= 0, got {light!r}")
            im["illumination"].append(None if light is None else float(light))

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, i: int):
        import imageio.v3 as iio

        im = self.images[i]
        path = self.image_dir / im["file_name"]
        try:
            arr = np.asarray(iio.imread(path))
        except Exception as err:  # noqa: BLE001 - any decoder error: name the file
            raise CocoFormatError(f"{path}: cannot read the image ({' '.join(str(err).split())})") from None
        if arr.ndim == 2:
            arr = np.repeat(arr[..., None], 3, axis=-1)
        arr = arr[..., :3]
        if arr.shape[:2] != (im["height"], im["width"]):
            raise CocoFormatError(
                f"{path}: image is {arr.shape[1]} x {arr.shape[0]}, the annotation file says "
                f"{im['width']} x {im['height']}"
            )
        scale = 65535.0 if arr.dtype == np.uint16 else 255.0
        img = torch.from_numpy(np.ascontiguousarray(arr.transpose(2, 0, 1))).float() / scale
        return img, {
            "boxes": torch.tensor(im["boxes"], dtype=torch.float32).reshape(-1, 4),
            "labels": torch.tensor(im["labels"], dtype=torch.int64),
            "image_id": im["id"],
        }
