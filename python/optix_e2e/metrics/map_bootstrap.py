"""COCO mAP of resampled image sets, for bootstrap intervals over images.

COCO matches detections to ground truth one image at a time (per class and IoU threshold:
detections in falling score order, each taking the unmatched box it overlaps most, if at
least the threshold), then pools every image's matched / unmatched detections into one
precision-recall curve per class. A resample of the images (with repeats) changes only the
pooling, so the matching is done once (``MatchTable``) and a resample is a weight per image:
the same 101-point interpolated AP, averaged over the classes with ground truth and the IoU
thresholds 0.50:0.05:0.95 (mAP) or at 0.5 (mAP@0.5), for every resample. On the whole set
(every weight 1) it equals torchmetrics' / pycocotools' figure (tested), at about a
thousandth of its cost per resample.

Conventions of COCO's evaluation kept here: area range "all", at most 100 detections per
image and class (highest scores), stable sorts, no crowd boxes.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError

IOU_THRESHOLDS = np.linspace(0.5, 0.95, 10)
RECALL_POINTS = np.linspace(0.0, 1.0, 101)


def _as_coco(boxes: torch.Tensor) -> torch.Tensor:
    """xyxy boxes as COCO holds them: x, y, width, height in float32, then overlaps in double
    (so an IoU at a threshold's edge falls on the same side as in COCO's evaluation)."""
    b = boxes.float()
    xywh = torch.cat([b[:, :2], b[:, 2:] - b[:, :2]], 1).double()
    return torch.cat([xywh[:, :2], xywh[:, :2] + xywh[:, 2:]], 1)


class MatchTable:
    """Per-image COCO matches of ``preds`` ({"boxes" xyxy, "scores", "labels"}) against
    ``targets`` ({"boxes", "labels"}); ``map(weights)`` scores a resample."""

    def __init__(self, preds: list[dict], targets: list[dict], max_dets: int = 100):
        from torchvision.ops import box_iou

        if len(preds) != len(targets):
            raise InputError(f"{len(preds)} detection lists for {len(targets)} images")
        classes = sorted(
            {int(c) for t in targets for c in t["labels"].tolist()}
            | {int(c) for p in preds for c in p["labels"].tolist()}
        )
        self.classes = classes
        self.n_images = len(targets)
        # per class: n_gt per image [N]; detections: image, score, matched per threshold [D, T]
        self.n_gt = {c: np.zeros(self.n_images) for c in classes}
        det_img, det_score, det_tp = ({c: [] for c in classes} for _ in range(3))
        for i, (p, t) in enumerate(zip(preds, targets)):
            for c in classes:
                g = t["boxes"][t["labels"] == c].float()
                sel = torch.nonzero(p["labels"] == c).flatten()
                order = torch.argsort(-p["scores"][sel], stable=True)[:max_dets]
                sel = sel[order]
                self.n_gt[c][i] = len(g)
                if not len(sel):
                    continue
                d = p["boxes"][sel].float()
                iou = box_iou(_as_coco(d), _as_coco(g)).numpy() if len(g) else np.zeros((len(d), 0))
                tp = np.zeros((len(d), len(IOU_THRESHOLDS)), bool)
                for k, thr in enumerate(IOU_THRESHOLDS):
                    taken = np.zeros(len(g), bool)
                    for j in range(len(d)):
                        best, m = min(thr, 1 - 1e-10), -1
                        for gi in range(len(g)):
                            if not taken[gi] and iou[j, gi] >= best:
                                best, m = iou[j, gi], gi
                        if m >= 0:
                            taken[m] = True
                            tp[j, k] = True
                det_img[c].append(np.full(len(d), i))
                det_score[c].append(p["scores"][sel].numpy())
                det_tp[c].append(tp)
        self._dets = {}
        for c in classes:
            if det_img[c]:
                img, score, tp = np.concatenate(det_img[c]), np.concatenate(det_score[c]), np.concatenate(det_tp[c])
                order = np.argsort(-score, kind="mergesort")
                self._dets[c] = (img[order], tp[order])
            else:
                self._dets[c] = (np.zeros(0, int), np.zeros((0, len(IOU_THRESHOLDS)), bool))

    def ap_table(self, weights=None) -> np.ndarray:
        """[classes with ground truth, T] 101-point interpolated AP of the resample ``weights`` [N]
        (how many times each image is drawn; None: the whole set once)."""
        w = np.ones(self.n_images) if weights is None else np.asarray(weights, float)
        rows = []
        for c in self.classes:
            n_gt = float(self.n_gt[c] @ w)
            if n_gt <= 0:
                continue  # COCO leaves a class without ground truth out of the mean
            img, tp = self._dets[c]
            dw = w[img][:, None]
            ctp, cfp = np.cumsum(dw * tp, 0), np.cumsum(dw * ~tp, 0)
            ap = np.zeros(len(IOU_THRESHOLDS))
            for k in range(len(IOU_THRESHOLDS)):
                keep = dw[:, 0] > 0  # an image drawn 0 times has no detections here
                tk, fk = ctp[keep, k], cfp[keep, k]
                if not len(tk):
                    continue
                recall = tk / n_gt
                precision = tk / np.maximum(tk + fk, np.finfo(float).eps)
                precision = np.maximum.accumulate(precision[::-1])[::-1]  # the envelope
                idx = np.searchsorted(recall, RECALL_POINTS, side="left")
                ok = idx < len(recall)
                ap[k] = np.where(ok, precision[np.minimum(idx, len(recall) - 1)], 0.0).mean()
            rows.append(ap)
        return np.array(rows).reshape(-1, len(IOU_THRESHOLDS))

    def scores(self, weights=None) -> dict:
        """{"map": mAP@[.5:.95], "map_50": mAP@0.5} of the resample (-1 where no class has ground truth)."""
        t = self.ap_table(weights)
        if not len(t):
            return {"map": -1.0, "map_50": -1.0}
        return {"map": float(t.mean()), "map_50": float(t[:, 0].mean())}
