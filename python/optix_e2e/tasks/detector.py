"""A small one-stage detector for the street scenes, and its mAP (issue 19 item 2).

What it is: torchvision's FCOS (Tian et al. 2019; anchor-free, one stage: per-location
classification with the focal loss, box regression with the GIoU loss, centre-ness, NMS),
built with ``weights=None`` so nothing is downloaded, on a compact backbone of our own: four
stride-2 stages of two 3x3 convolutions with GroupNorm (``width`` to 4 x ``width`` channels)
and torchvision's FeaturePyramidNetwork (``fpn`` channels) at strides 4, 8, 16 and 32, so an
8-pixel object still falls on a level with cells smaller than itself. Why: a ResNet-50 or
MobileNet backbone trained from scratch costs 10-100x more per step on this 2-core CPU and
needs far more data than a few thousand drawn scenes; the detection machinery (losses,
target assignment, decoding, NMS) is the library's, tested by its maintainers.

mAP: torchmetrics' ``MeanAveragePrecision`` (COCO's definition: mAP@[.5:.95] and mAP@0.5,
101-point interpolation) with the faster-coco-eval backend, which works offline.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
from torch import nn

from ..precision import network_autocast, to_float32
from ..scenes.street import CATEGORIES

#: FCOS counts the background as a class: COCO ids 1..4 -> 5 outputs
NUM_CLASSES = len(CATEGORIES) + 1


def _stage(cin: int, cout: int) -> nn.Sequential:
    def gn(c):
        return nn.GroupNorm(min(8, c // 4), c)

    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, 2, 1, bias=False),
        gn(cout),
        nn.SiLU(),
        nn.Conv2d(cout, cout, 3, 1, 1, bias=False),
        gn(cout),
        nn.SiLU(),
    )


class TinyBackbone(nn.Module):
    """[B, 3, H, W] -> FPN features at strides 4, 8, 16, 32, ``out_channels`` each."""

    #: --precision (optix_e2e.precision): the autocast dtype, None for float32; the features
    #: leave in float32
    autocast_dtype: "torch.dtype | None" = None

    def __init__(self, width: int = 32, fpn: int = 64):
        super().__init__()
        from torchvision.ops import FeaturePyramidNetwork

        chans = [width, 2 * width, 4 * width, 4 * width]
        self.stem = _stage(3, width // 2)
        self.stages = nn.ModuleList([_stage(width // 2, chans[0])] + [_stage(a, b) for a, b in zip(chans, chans[1:])])
        self.fpn = FeaturePyramidNetwork(chans, fpn)
        self.out_channels = fpn

    def forward(self, x: torch.Tensor) -> "OrderedDict[str, torch.Tensor]":
        with network_autocast(x, self.autocast_dtype):
            x = self.stem(x)
            feats = OrderedDict()
            for k, stage in enumerate(self.stages):
                x = stage(x)
                feats[f"p{k + 2}"] = x
            return to_float32(self.fpn(feats))


def _head_class():
    """torchvision's FCOS head with the precision switch: its convolutions under autocast, its
    outputs (logits, box regression, centre-ness) back in float32, so FCOS's losses (focal, GIoU,
    centre-ness BCE), decoding and NMS stay float32. The same parameters and initialization as
    the head FCOS builds itself (the same class underneath)."""
    global _HEAD
    if _HEAD is None:
        from torchvision.models.detection.fcos import FCOSHead

        class FCOSHeadWithPrecision(FCOSHead):
            autocast_dtype: "torch.dtype | None" = None

            def forward(self, x):
                with network_autocast(x[0], self.autocast_dtype):
                    return to_float32(super().forward(x))

        FCOSHeadWithPrecision.__qualname__ = FCOSHeadWithPrecision.__name__  # found by pickle (__getattr__)
        _HEAD = FCOSHeadWithPrecision
    return _HEAD


_HEAD = None


def __getattr__(name: str):
    """The head's class, made on first use (torchvision is imported late)."""
    if name == "FCOSHeadWithPrecision":
        return _head_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def make_detector(
    width: int = 32, fpn: int = 64, image_size: tuple[int, int] = (256, 384), score_thresh: float = 0.05
) -> nn.Module:
    """The FCOS detector on ``TinyBackbone``; images of ``image_size`` are used at that size
    (no resizing). Input: a list of [3, H, W] sRGB images in [0, 1]; in training also a list
    of {"boxes" [N, 4] xyxy, "labels" [N] (COCO ids)}, returning the loss terms; in eval, a
    list of {"boxes", "scores", "labels"}."""
    from torchvision.models.detection import FCOS
    from torchvision.models.detection.anchor_utils import AnchorGenerator

    h, w = image_size
    anchors = AnchorGenerator(sizes=((8,), (16,), (32,), (64,)), aspect_ratios=((1.0,),) * 4)
    backbone = TinyBackbone(width, fpn)
    # the head FCOS would build (same class, arguments and place in the seeded draws), with the switch
    head = _head_class()(backbone.out_channels, anchors.num_anchors_per_location()[0], NUM_CLASSES)
    return FCOS(
        backbone,
        NUM_CLASSES,
        min_size=min(h, w),
        max_size=max(h, w),
        image_mean=[0.45, 0.45, 0.45],
        image_std=[0.25, 0.25, 0.25],
        anchor_generator=anchors,
        head=head,
        score_thresh=score_thresh,
        detections_per_img=100,
    )


def mean_average_precision(preds: list[dict], targets: list[dict]) -> dict:
    """COCO mAP of detections ``preds`` ({"boxes", "scores", "labels"}) against ``targets``
    ({"boxes", "labels"}), boxes xyxy: ``map`` (mAP@[.5:.95]), ``map_50``, ``map_75``, and
    the number of target objects."""
    from torchmetrics.detection import MeanAveragePrecision

    m = MeanAveragePrecision(box_format="xyxy", iou_type="bbox", backend="faster_coco_eval")
    m.update(
        [{k: p[k].detach().cpu() for k in ("boxes", "scores", "labels")} for p in preds],
        [{k: t[k].detach().cpu() for k in ("boxes", "labels")} for t in targets],
    )
    r = m.compute()
    return {
        "map": float(r["map"]),
        "map_50": float(r["map_50"]),
        "map_75": float(r["map_75"]),
        "n_objects": int(sum(len(t["labels"]) for t in targets)),
    }


def in_the_dark(
    preds: list[dict], targets: list[dict], lights: list[torch.Tensor], dark: float = 0.1
) -> tuple[list[dict], list[dict]]:
    """Detections and targets restricted to the objects lit under ``dark`` (``lights``: each
    target's mean illumination, a fraction of the sunlight): the other objects' boxes are
    removed from the targets, and detections matching one of them (IoU >= 0.5) from the
    detections (they are that object's, not false positives in the dark)."""
    from torchvision.ops import box_iou

    dp, dt = [], []
    for p, t, light in zip(preds, targets, lights):
        keep = torch.as_tensor(light, dtype=torch.float32).reshape(-1) < dark
        drop = t["boxes"][~keep]
        far = (
            box_iou(p["boxes"], drop).max(1).values < 0.5
            if len(drop) and len(p["boxes"])
            else torch.ones(len(p["boxes"]), dtype=torch.bool)
        )
        dp.append({k: v[far] for k, v in p.items()})
        dt.append({"boxes": t["boxes"][keep], "labels": t["labels"][keep]})
    return dp, dt


@torch.no_grad()
def detect(model: nn.Module, images: torch.Tensor, batch: int = 8) -> list[dict]:
    """The model's detections for images [N, 3, H, W] (eval mode, in batches): each batch goes
    to the model's device, the detections come back to the CPU (where mAP is scored)."""
    was = model.training
    model.eval()
    dev = next(model.parameters(), images).device  # (a model without weights: the images' own)
    out = []
    for i in range(0, len(images), batch):
        out += [{k: v.cpu() for k, v in p.items()} for p in model(list(images[i : i + batch].to(dev)))]
    model.train(was)
    return out
