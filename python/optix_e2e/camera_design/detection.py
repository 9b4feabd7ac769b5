"""Detection in the design run (`optix design detection --out DIR`): paper Sec. 6.1 "Automotive
object detection" (Eq. 12, Table 4) on our street scenes.

As the image-quality tasks (image_quality.py), with the detector as a third block:

* ``end_to_end``: lens (surrogate optics, the f-number among its parameters), the hardware
  ISP's hyperparameters (through its proxy) and the detector's weights, by Alg. 1 or vanilla;
* ``nominal``: the nominal lens (f/4.4) fixed, the ISP hyperparameters and the detector
  fine-tuned together on the same loss, batches, noise and number of steps;

both from the same pre-trained detector (trained on noise-free renderings of street scenes,
``optix detect train``) and the same ISP initialization. Both cameras are then evaluated on
held-out street scenes under the exact engine's PSFs and vignetting of their lens, at their
lens's f-number (Eq. 3), through the true reference ISP, with the same noise draws: COCO
mAP@0.5 and mAP@[.5:.95] for each, the same over the objects in the dark, and the paired
differences with a 95 % bootstrap interval over scenes (each resample scored by mAP as a whole).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch
from torchvision.utils import draw_bounding_boxes
from tqdm import tqdm

from .. import color, parallel
from ..camera import Camera, FixedOptics
from ..errors import InputError
from ..io import write_csv_atomic
from ..metrics.map_bootstrap import MatchTable
from ..precision import apply_precision, resolve_precision
from ..scenes.street import CATEGORIES
from ..tasks import SensorFrame, get_task
from ..tasks.detection import DetectionCamera, heldout_streets, street_batch
from ..tasks.detector import in_the_dark, make_detector, mean_average_precision
from ..tasks.detector_train import load_detector
from ..tasks.shipped_detectors import detector_file
from . import eval_cache
from .build import build_camera
from .config import DesignConfig
from .outputs import save_panels
from .task_hooks import TaskHooks

PANEL_SCORE = 0.3  # detections drawn in the panels: score at least this


def load_start_detector(cfg: DesignConfig, size: tuple[int, int]) -> torch.nn.Module:
    """The pre-trained detector both trainings start from, built for crops of ``size``."""
    path = detector_file(cfg.detector)
    if not path.is_file():
        raise FileNotFoundError(f"the pre-trained detector is missing: {path}")
    model, ck = load_detector(path)
    det = make_detector(int(ck["config"]["width"]), int(ck["config"]["fpn"]), size)
    det.load_state_dict(model.state_dict())
    return det


def build_detection_camera(
    cfg: DesignConfig,
    sur,
    *,
    fixed_optics: FixedOptics | None = None,
    frame: SensorFrame = SensorFrame(),
    device: "torch.device | str" = "cpu",
) -> DetectionCamera:
    cam = DetectionCamera(
        build_camera(cfg, sur, fixed_optics=fixed_optics, frame=frame, device=device),
        load_start_detector(cfg, cfg.crop_hw),
    ).to(device)
    apply_precision(cam, resolve_precision(cfg.precision, device, option="precision"))  # ISP net and detector
    return cam


def _loss_at(cfg: DesignConfig, cam: DetectionCamera, frame: SensorFrame, ranks: parallel.Ranks = parallel.Ranks()):
    task = get_task(cfg.task)
    part = parallel.batch_slice(cfg.batch, ranks)  # this rank's scenes of each batch (torchrun)

    def loss_at(t: int, gen: torch.Generator):
        b = street_batch(cfg.seed, t, cfg.batch, cfg.crop_hw, cam.margin, (task.level_min, task.level_max), frame)
        dev = cam.device  # the batch is drawn on the CPU (seeded) and goes to the camera once
        targets = [{k: v.to(dev) for k, v in tg.items()} for tg in b.targets[part]]
        return cam(b.scene[part].to(dev), b.offset_px, gen, targets)

    return loss_at


@torch.no_grad()
def evaluate_detection(cam: DetectionCamera, samples, progress: bool = False, desc: str = "eval") -> list[dict]:
    """Each held-out sample through the camera's final output (reference ISP, 8 bits, the
    sample's noise seed) and the detector: {"boxes", "scores", "labels"} per sample."""
    cam.eval()
    preds = []
    for s in tqdm(samples, desc=desc, unit="scene", disable=not progress, leave=False):
        gen = torch.Generator().manual_seed(int(s.noise_seed))
        img = cam.final_image(s.scene[None].to(cam.device), s.offset_px, gen)
        preds += cam.detect(img)
    return [{k: v.detach().cpu() for k, v in p.items()} for p in preds]


def detection_scores(preds: list[dict], samples, dark: float) -> dict:
    targets = [s.target for s in samples]
    res = mean_average_precision(preds, targets)
    r = mean_average_precision(*in_the_dark(preds, targets, [s.object_light for s in samples], dark))
    res["dark"] = {"threshold": dark, "map_50": r["map_50"], "map": r["map"], "n_objects": r["n_objects"]}
    return res


def map_resamples(preds: list[dict], samples, n_boot: int, seed: int, dark: float) -> dict:
    """One camera's mAP@0.5 and mAP on ``samples`` and on each of ``n_boot`` bootstrap
    resamples of the scenes (drawn from ``seed``: every camera scored with the same seed is
    scored on the same resamples), for all objects and for those in the dark:
    {"all" | "dark": {"full": {k: x}, "boots": {k: [n_boot]}}} (k: map_50, map). COCO
    matching is done once per image (metrics.map_bootstrap); ``paired_resamples`` pairs two."""
    n = len(samples)
    targets = [s.target for s in samples]
    dark_p, dark_t = in_the_dark(preds, targets, [s.object_light for s in samples], dark)
    rng = np.random.default_rng(seed)
    counts = np.stack([np.bincount(rng.integers(0, n, n), minlength=n) for _ in range(n_boot)])
    out = {}
    for zone, table in (("all", MatchTable(preds, targets)), ("dark", MatchTable(dark_p, dark_t))):
        full, boots = table.scores(), [table.scores(w) for w in counts]
        out[zone] = {
            "full": {k: full[k] for k in ("map_50", "map")},
            "boots": {k: np.array([b[k] for b in boots]) for k in ("map_50", "map")},
        }
    return out


def paired_resamples(a: dict, b: dict) -> dict:
    """mAP(b) - mAP(a) from two cameras' ``map_resamples`` of the same scenes and seed, with
    the 95 % percentile interval of the resampled differences."""
    n_boot = len(a["all"]["boots"]["map"])
    out: dict = {"n_boot": n_boot, "dark": {}}
    for zone in ("all", "dark"):
        za, zb = a[zone], b[zone]
        for k in ("map_50", "map"):
            lo, hi = np.percentile(zb["boots"][k] - za["boots"][k], [2.5, 97.5])
            entry = {"mean": float(zb["full"][k] - za["full"][k]), "ci95": [float(lo), float(hi)], "better": "higher"}
            (out if zone == "all" else out["dark"])[k] = entry
    return out


def paired_map(a: list[dict], b: list[dict], samples, n_boot: int, seed: int, dark: float) -> dict:
    """mAP(b) - mAP(a) on the same scenes, with a 95 % percentile bootstrap interval over scenes
    (each resample scored as a whole set, both cameras on the same resample; COCO matching
    done once per image, metrics.map_bootstrap), for all objects and those in the dark."""
    ra, rb = (map_resamples(p, samples, n_boot, seed, dark) for p in (a, b))
    return {"n_images": len(samples), **paired_resamples(ra, rb)}


def _digest(psf, vig, fh, f_number, cam: DetectionCamera, n: int, samples_key: str) -> str:
    """What a held-out evaluation depends on besides the run's settings (eval_cache): the
    camera's PSFs, vignetting, field heights, f-number, ISP, detector and sensor, the held-out
    scenes (``samples_key``: eval_cache.samples_digest, once per evaluation) and the code."""
    tensors = (psf, vig, fh, *cam.isp.state_dict().values(), *cam.detector.state_dict().values())
    return eval_cache.evaluation_key(
        f"scenes={n} f={f_number!r}",
        samples=samples_key,
        sensor=eval_cache.sensor_digest(cam.sensor),
        tensors=tensors,
    )


def _preds_json(preds: list[dict]) -> list[dict]:
    return [
        {"boxes": p["boxes"].tolist(), "scores": p["scores"].tolist(), "labels": p["labels"].tolist()} for p in preds
    ]


def _preds_from_json(rows: list[dict]) -> list[dict]:
    return [
        {
            "boxes": torch.tensor(r["boxes"], dtype=torch.float32).reshape(-1, 4),
            "scores": torch.tensor(r["scores"], dtype=torch.float32),
            "labels": torch.tensor(r["labels"], dtype=torch.int64),
        }
        for r in rows
    ]


def read_detections(path: Path, key: str) -> tuple[list[dict], float] | None:
    """(detections, seconds they took) of an earlier evaluation saved at ``path`` under ``key``
    (eval_cache); None where absent, stale or damaged (hand-edited, cut short): evaluate again."""
    cached = eval_cache.read(path, key)
    if cached is None:
        return None
    try:
        return _preds_from_json(cached["detections"]), float(cached.get("wall_s", 0.0))
    except (KeyError, TypeError, ValueError, RuntimeError):
        return None


def write_detections(path: Path, key: str, wall_s: float, samples, preds: list[dict]) -> None:
    """An evaluation's detections of ``samples`` at ``path`` under ``key`` (read_detections)."""
    eval_cache.write(path, key, wall_s, images=[s.name for s in samples], detections=_preds_json(preds))


def saved_detections(path: Path, samples) -> list[dict] | None:
    """The detections a run saved at ``path``, whatever its key, if they are of ``samples`` (None:
    absent, unreadable or of other scenes): for comparing runs' saved cameras."""
    try:
        d = json.loads(Path(path).read_text())
        if d.get("images") != [s.name for s in samples]:
            return None
        return _preds_from_json(d["detections"])
    except (OSError, KeyError, TypeError, ValueError, RuntimeError, AttributeError):
        return None


WHO = ("nominal", "end_to_end")


class DetectionHooks(TaskHooks):
    loss_parts = DetectionCamera.LOSS_PARTS
    # a fast lens whose FFT PSF the engine refuses gets the Huygens PSF (the reference), noted
    exact_fallback = "huygens"

    def check(self, sur, ranks):
        c = self.cfg
        if c.images or c.photos:
            raise InputError(
                f"{'--images' if c.images else 'photos'} is for the image-quality tasks; detection trains on street scenes"
            )
        if c.fields:
            raise InputError("fields: the detection run renders from all the surrogate's field samples (fields = 0)")
        if c.optics not in ("surrogate", "exact", "auto"):
            raise InputError(
                f"optics {c.optics}: the detection run trains through the surrogate or the engine (exact); "
                f"hybrid optics are for the image-quality tasks"
            )
        if c.optics == "exact" and ranks.distributed:
            raise InputError(
                "optics exact runs the engine inside the training steps, which is not shared between "
                "torchrun processes: run it in one process"
            )
        if c.optics != "exact" and not sur.has_network:
            raise InputError(f"optics {c.optics}: {sur.no_network_why}")
        if "f_number" not in sur.param_names:
            raise InputError(
                f"surrogate {c.surrogate}: its space has no f_number parameter; the detection task "
                f"learns the aperture (use paper-triplet-detect)"
            )
        self.f_index = sur.param_names.index("f_number")

    def build_camera(self, sur, frame, *, fixed_optics=None, trained=False):
        cam = build_camera(self.cfg, sur, fixed_optics=fixed_optics, frame=frame, device=self.device)
        if fixed_optics is None and self.cfg.optics == "exact":
            cam.optics.backend = "exact"  # every lens step on the engine's PSFs and Jacobian
        cam = DetectionCamera(cam, load_start_detector(self.cfg, self.cfg.crop_hw)).to(self.device)
        apply_precision(cam, resolve_precision(self.cfg.precision, self.device, option="precision"))
        return cam

    def loss_at(self, camera, frame, ranks):
        return _loss_at(self.cfg, camera, frame, ranks)

    def nominal_optics(self, camera, sur, nominal_values, surrogate_psfs, frame):
        # the baseline trains through the run's optics model: the engine's PSFs of the nominal
        # lens under exact optics (as the image-quality tasks), the surrogate's otherwise
        psf, vig = surrogate_psfs
        if self.cfg.optics == "exact":
            psf, vig = (
                torch.as_tensor(a, dtype=torch.float32, device=nominal_values.device)
                for a in camera.optics.exact.psfs(nominal_values.double().cpu().numpy())
            )
        return FixedOptics(
            psf,
            vig,
            camera.optics.render_fields,
            patch=self.cfg.patch,
            full_field_px=frame.full_field_px,
            f_number=self.f_number(nominal_values),
        )

    def f_number(self, values):
        return float(values[self.f_index])

    def evaluate(self, run):
        c, task = self.cfg, self.task
        out, cams, optics, f_numbers, frame = run.out, run.cams, run.optics, run.f_numbers, run.frame
        exact, progress = run.exact, run.progress
        samples = heldout_streets(
            c.eval_scenes, c.crop_hw, exact["psf"].shape[-1] // 2, (task.level_min, task.level_max), frame
        )
        samples_key = eval_cache.samples_digest(samples)  # once per evaluation
        preds: dict[str, dict[str, list]] = {}
        reused_s = 0.0
        for who in WHO:
            preds[who] = {}
            for kind in ("exact", "surrogate"):
                if optics[who][kind] is None:  # no network on these terms (a space of other parameters)
                    continue
                path = out / f"detections_{who}_{kind}.json"
                psf, vig, fh = optics[who][kind]
                key = _digest(psf, vig, fh, f_numbers[who], cams[who], len(samples), samples_key)
                cached = read_detections(path, key)
                if cached is not None:
                    preds[who][kind], wall_s = cached
                    reused_s += wall_s
                    continue
                t0 = time.perf_counter()
                fo = FixedOptics(
                    psf, vig, fh, patch=c.patch, full_field_px=frame.full_field_px, f_number=f_numbers[who]
                ).to(self.device)
                ev_cam = DetectionCamera(Camera(fo, cams[who].sensor, cams[who].isp), cams[who].detector)
                preds[who][kind] = evaluate_detection(ev_cam, samples, progress, f"eval {who} ({kind} optics)")
                write_detections(path, key, time.perf_counter() - t0, samples, preds[who][kind])
        scores = {who: {kind: detection_scores(p, samples, task.dark) for kind, p in preds[who].items()} for who in WHO}
        return {"samples": samples, "preds": preds, "scores": scores}, reused_s

    def panels(self, run, path):
        ev = run.evaluation
        _detection_panels(
            path, ev["samples"], ev["preds"], run.optics, run.cams, run.f_numbers, self.cfg.patch, run.frame
        )

    def summarize(self, run):
        evaluation, reports, f_numbers = run.evaluation, run.reports, run.f_numbers
        scores, preds, c = evaluation["scores"], evaluation["preds"], self.cfg

        def camera_summary(who: str) -> dict:
            s = scores[who]["exact"]
            rep = reports[who]
            return {
                "map_50": s["map_50"],
                "map": s["map"],
                "map_75": s["map_75"],
                "n_objects": s["n_objects"],
                "dark": s["dark"],
                "f_number": f_numbers[who],
                "f_number_paraxial": float(rep["paraxial"]["f_number"]),
                "rms_spot_um": [float(r["rms_spot_um"]) for r in rep["fields"]],
                "relative_illumination": [r["relative_illumination"] for r in rep["fields"]],
                "report_fields_deg": [float(r["field_deg"]) for r in rep["fields"]],
                # under the surrogate's PSFs, for reference (None: no network on these terms)
                "surrogate": (
                    {k: scores[who]["surrogate"][k] for k in ("map_50", "map", "dark")}
                    if "surrogate" in scores[who]
                    else None
                ),
            }

        paired = paired_map(
            preds["nominal"]["exact"],
            preds["end_to_end"]["exact"],
            evaluation["samples"],
            c.bootstrap,
            c.seed,
            self.task.dark,
        )
        return {"nominal": camera_summary("nominal"), "end_to_end": camera_summary("end_to_end"), "paired": paired}

    def held_out(self, run):
        s = run.evaluation["scores"]["nominal"]["exact"]
        return {
            "n_images": len(run.evaluation["samples"]),
            "n_objects": s["n_objects"],
            "n_objects_dark": s["dark"]["n_objects"],
            "size_px": list(self.cfg.crop_hw),
            "levels": [self.task.level_min, self.task.level_max],
        }

    def extra(self, run, monitor, e2e):
        cams = run.cams
        optics = cams["end_to_end"].optics
        model = {
            "mode": "exact" if self.cfg.optics == "exact" else "surrogate",
            # the network's error is measured at the final design (surrogate_psf_rel_l1_per_field)
            "network": optics.surrogate.has_network,
        }
        if not optics.surrogate.has_network:
            model["no_network"] = optics.surrogate.no_network_why
        if self.cfg.optics == "exact":
            ex = optics.exact
            model["engine"] = {
                "designs": ex.designs_computed,
                "seconds": ex.seconds,
                # lens steps on the engine's one-pass gradient, and by differences where it had none
                "gradient": ex.gradient,
                "one_pass_gradients": ex.one_pass,
                "difference_fallbacks": ex.fallbacks,
            }
            if ex.step_choice is not None:
                model["steps"] = ex.step_choice.to_json()
        return {
            "isp_hyperparameters": {who: cams[who].isp.hyperparameters() for who in WHO},
            "optics_model": model,
        }

    def write_tables(self, run):
        _write_scenes(run.out / "metrics.csv", run.evaluation["samples"], run.evaluation["preds"])

    @staticmethod
    def summary_lines(res):
        n, e, p = res["nominal"], res["end_to_end"], res["paired"]
        h = res["held_out"]
        lines = [
            f"held-out ({h['n_images']} street scenes, {h['n_objects']} objects, {h['n_objects_dark']} in the dark), "
            f"exact optics, reference ISP:",
            f"  f-number  nominal f/{n['f_number']:.2f}   end-to-end f/{e['f_number']:.2f}",
        ]
        for k, label in (("map_50", "mAP@0.5"), ("map", "mAP")):
            lo, hi = p[k]["ci95"]
            lines.append(
                f"  {label:8s} nominal {n[k]:.4f}   end-to-end {e[k]:.4f}   diff {p[k]['mean']:+.4f} "
                f"[{lo:+.4f}, {hi:+.4f}]"
            )
        return lines


def _write_scenes(path: Path, samples, preds: dict) -> None:
    """Per held-out scene: where it lies, its light, its objects, and each camera's detections
    at score >= 0.3 under exact optics."""
    write_csv_atomic(
        path,
        (
            [
                s.name,
                f"{s.radius:.4f}",
                f"{s.level:.4f}",
                len(s.target["labels"]),
                int((s.object_light < 0.1).sum()),
                *(int((preds[who]["exact"][i]["scores"] >= PANEL_SCORE).sum()) for who in preds),
            ]
            for i, s in enumerate(samples)
        ),
        header=["image", "radius", "level", "n_objects", "n_dark", *(f"n_detections_{who}" for who in preds)],
    )


@torch.no_grad()
def _detection_panels(
    path: Path,
    samples,
    preds: dict,
    optics: dict,
    cams: dict,
    f_numbers: dict,
    patch: int,
    frame: SensorFrame,
    n_scenes: int = 3,
) -> None:
    """The held-out scenes with the most objects in the dark: the ideal image with its boxes,
    then each camera's output (exact optics, reference ISP) with its detections (score >= 0.3)."""
    names = {c["id"]: c["name"] for c in CATEGORIES}
    order = sorted(range(len(samples)), key=lambda i: -int((samples[i].object_light < 0.1).sum()))[:n_scenes]

    def boxed(img: torch.Tensor, boxes, labels, colour) -> torch.Tensor:
        u8 = (img.clamp(0, 1) * 255).round().to(torch.uint8)
        if len(boxes):
            u8 = draw_bounding_boxes(
                u8, boxes, [names.get(int(k), str(int(k))) for k in labels], colors=colour, width=1
            )
        return u8.float() / 255

    rows = []
    for i in order:
        s = samples[i]
        m = (s.scene.shape[-2] - s.size[0]) // 2
        inner = s.scene[:, m : m + s.size[0], m : m + s.size[1]]
        ideal = color.linear_to_srgb((inner / s.level).clamp(0, 1))
        imgs = [boxed(ideal, s.target["boxes"], s.target["labels"], "yellow")]
        for who in ("nominal", "end_to_end"):
            psf, vig, fh = optics[who]["exact"]
            fo = FixedOptics(psf, vig, fh, patch=patch, full_field_px=frame.full_field_px, f_number=f_numbers[who])
            cam = DetectionCamera(Camera(fo.to(cams[who].device), cams[who].sensor, cams[who].isp), cams[who].detector)
            gen = torch.Generator().manual_seed(int(s.noise_seed))
            img = cam.final_image(s.scene[None].to(cam.device), s.offset_px, gen)[0].cpu()
            p = preds[who]["exact"][i]
            keep = p["scores"] >= PANEL_SCORE
            imgs.append(boxed(img, p["boxes"][keep], p["labels"][keep], "cyan"))
        rows.append((f"{s.name} (r {s.radius:.2f}, {int((s.object_light < 0.1).sum())} in the dark)", imgs))
    save_panels(
        path,
        rows,
        [
            "scene (ideal, at sunlit exposure) + boxes",
            f"nominal f/{f_numbers['nominal']:.2f} + fine-tuned",
            f"end-to-end f/{f_numbers['end_to_end']:.2f}",
        ],
    )
