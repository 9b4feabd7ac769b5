"""The detection design run (`optix design detection --out DIR`): paper Sec. 6.1 "Automotive
object detection" (Eq. 12, Table 4) on our street scenes.

As the image-quality runs (optimize/run.py), with the detector as a third block:

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

import hashlib
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .. import parallel
from ..camera import Camera, FixedOptics
from ..io import write_json_atomic
from ..lens import Lens
from ..surrogate.exact import exact_optics
from ..tasks import SensorFrame, get_task
from ..tasks.detection import DetectionCamera, heldout_streets, street_batch
from ..tasks.detector import in_the_dark, make_detector, mean_average_precision
from . import outputs
from .config import DesignConfig
from .run import build_camera, design_field_heights, start_run, train

BUNDLED_DETECTOR = Path(__file__).resolve().parent.parent / "tasks" / "bundled" / "street_detector.pt"
PANEL_SCORE = 0.3  # detections drawn in the panels: score at least this


def load_start_detector(cfg: DesignConfig, size: tuple[int, int]) -> torch.nn.Module:
    """The pre-trained detector both trainings start from, built for crops of ``size``."""
    from ..tasks.detector_train import load_detector

    path = Path(cfg.detector) if cfg.detector else BUNDLED_DETECTOR
    if not path.is_file():
        raise FileNotFoundError(f"the pre-trained detector is missing: {path}")
    model, ck = load_detector(path)
    det = make_detector(int(ck["config"]["width"]), int(ck["config"]["fpn"]), size)
    det.load_state_dict(model.state_dict())
    return det


def build_detection_camera(
    cfg: DesignConfig, sur, *, fixed_optics: FixedOptics | None = None, frame: SensorFrame = SensorFrame()
) -> DetectionCamera:
    return DetectionCamera(
        build_camera(cfg, sur, fixed_optics=fixed_optics, frame=frame), load_start_detector(cfg, cfg.crop_hw)
    )


def _loss_at(cfg: DesignConfig, cam: DetectionCamera, frame: SensorFrame, ranks: parallel.Ranks = parallel.Ranks()):
    task = get_task(cfg.task)
    part = parallel.batch_slice(cfg.batch, ranks)  # this rank's scenes of each batch (torchrun)

    def loss_at(t: int, gen: torch.Generator):
        b = street_batch(cfg.seed, t, cfg.batch, cfg.crop_hw, cam.margin, (task.level_min, task.level_max), frame)
        return cam(b.scene[part], b.offset_px, gen, b.targets[part])

    return loss_at


@torch.no_grad()
def evaluate_detection(cam: DetectionCamera, samples, progress: bool = False, desc: str = "eval") -> list[dict]:
    """Each held-out sample through the camera's final output (reference ISP, 8 bits, the
    sample's noise seed) and the detector: {"boxes", "scores", "labels"} per sample."""
    cam.eval()
    preds = []
    for s in tqdm(samples, desc=desc, unit="scene", disable=not progress, leave=False):
        img = cam.final_image(s.scene[None], s.offset_px, torch.Generator().manual_seed(int(s.noise_seed)))
        preds += cam.detect(img)
    return [{k: v.detach().cpu() for k, v in p.items()} for p in preds]


def detection_scores(preds: list[dict], samples, dark: float) -> dict:
    targets = [s.target for s in samples]
    res = mean_average_precision(preds, targets)
    r = mean_average_precision(*in_the_dark(preds, targets, [s.object_light for s in samples], dark))
    res["dark"] = {"threshold": dark, "map_50": r["map_50"], "map": r["map"], "n_objects": r["n_objects"]}
    return res


def paired_map(a: list[dict], b: list[dict], samples, n_boot: int, seed: int, dark: float) -> dict:
    """mAP(b) - mAP(a) on the same scenes, with a 95 % percentile bootstrap interval over scenes
    (each resample scored as a whole set, both cameras on the same resample; COCO matching
    done once per image, metrics.map_bootstrap), for all objects and those in the dark."""
    from ..metrics.map_bootstrap import MatchTable

    n = len(samples)
    targets = [s.target for s in samples]
    lights = [s.object_light for s in samples]
    dark_a, dark_t = in_the_dark(a, targets, lights, dark)
    dark_b, _ = in_the_dark(b, targets, lights, dark)
    tables = {
        "all": (MatchTable(a, targets), MatchTable(b, targets)),
        "dark": (MatchTable(dark_a, dark_t), MatchTable(dark_b, dark_t)),
    }
    rng = np.random.default_rng(seed)
    counts = np.stack([np.bincount(rng.integers(0, n, n), minlength=n) for _ in range(n_boot)])
    out: dict = {"n_images": n, "n_boot": n_boot, "dark": {}}
    for z, (ta, tb) in tables.items():
        full_a, full_b = ta.scores(), tb.scores()
        boots = [(ta.scores(w), tb.scores(w)) for w in counts]
        for k in ("map_50", "map"):
            d = np.array([sb[k] - sa[k] for sa, sb in boots])
            lo, hi = np.percentile(d, [2.5, 97.5])
            entry = {"mean": float(full_b[k] - full_a[k]), "ci95": [float(lo), float(hi)], "better": "higher"}
            (out if z == "all" else out["dark"])[k] = entry
    return out


def _digest(psf, vig, fh, f_number, cam: DetectionCamera, n: int) -> str:
    h = hashlib.sha256(f"scenes={n} f={f_number!r}".encode())
    for t in (psf, vig, fh, *cam.isp.state_dict().values(), *cam.detector.state_dict().values()):
        h.update(torch.as_tensor(t).detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


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


def run_detection_design(cfg: DesignConfig, out: "str | Path", *, progress: bool = True, log=print) -> dict | None:
    """The whole detection run; returns the results (also written to out/results.json).
    Under torchrun, as run_design: the ranks share the batches, rank 0 evaluates and writes."""
    from ..design.report import write_report
    from .run import _write_history, claim_run_dir

    ranks = parallel.setup("cpu")
    out, task, frame, sur = start_run(cfg, out)
    if cfg.fields:
        raise ValueError("fields: the detection run renders from all the surrogate's field samples (fields = 0)")
    if cfg.optics not in ("surrogate", "auto"):
        raise ValueError(
            f"optics {cfg.optics}: the detection run trains through the surrogate (exact and hybrid "
            f"optics are for the image-quality tasks)"
        )
    if "f_number" not in sur.param_names:
        raise ValueError(
            f"surrogate {cfg.surrogate}: its space has no f_number parameter; the detection task "
            f"learns the aperture (use paper-triplet-detect)"
        )
    build_detection_camera(cfg, sur, frame=frame)  # everything is checked before the run directory is claimed
    progress, log, writer = claim_run_dir(out, cfg, ranks, progress, log)
    parts = DetectionCamera.LOSS_PARTS
    try:
        log(f"[1/4] end-to-end training: {cfg.task}, {cfg.optimizer}, {cfg.total_steps} steps")
        cam = build_detection_camera(cfg, sur, frame=frame)
        opt_kind = cfg.optimizer
        from .run import make_optimizer

        e2e = train(
            cfg,
            cam,
            make_optimizer(cfg, cam, opt_kind),
            out,
            "end_to_end",
            progress=progress,
            writer=writer,
            frame=frame,
            log=log,
            loss_at=_loss_at(cfg, cam, frame, ranks),
            parts=parts,
            ranks=ranks,
        )
        nominal_values = cam.optics.base_values()
        n_nominal = float(nominal_values[sur.param_names.index("f_number")])
        with torch.no_grad():
            psf_ns, vig_ns = sur.psfs(nominal_values, check=False)
        fixed = FixedOptics(
            psf_ns,
            vig_ns,
            cam.optics.render_fields,
            patch=cfg.patch,
            full_field_px=frame.full_field_px,
            f_number=n_nominal,
        )
        log(f"[2/4] nominal lens + ISP and detector fine-tuned, the same {cfg.total_steps} steps")
        nom_cam = build_detection_camera(cfg, sur, fixed_optics=fixed, frame=frame)
        nom = train(
            cfg,
            nom_cam,
            make_optimizer(cfg, nom_cam, "nominal"),
            out,
            "nominal",
            progress=progress,
            writer=writer,
            frame=frame,
            log=log,
            loss_at=_loss_at(cfg, nom_cam, frame, ranks),
            parts=parts,
            ranks=ranks,
        )
    finally:
        if writer is not None:
            writer.close()
    if not ranks.is_main:
        return None

    t_eval = time.perf_counter()
    log("[3/4] exact PSFs of both lenses (engine) and held-out evaluation")
    final_values = cam.optics.values().detach()
    values = {"nominal": nominal_values, "end_to_end": final_values}
    f_numbers = {who: float(v[sur.param_names.index("f_number")]) for who, v in values.items()}
    # a fast lens whose FFT PSF the engine refuses gets the Huygens PSF (the reference), noted
    exact = exact_optics(sur, torch.stack([nominal_values, final_values]).double().numpy(), fallback="huygens")
    with torch.no_grad():
        psf_es, vig_es = sur.psfs(final_values, check=False)
    heights = {
        who: design_field_heights(sur, v.numpy(), exact["image_distance"][i])
        for i, (who, v) in enumerate(values.items())
    }
    h_train = cam.optics.render_fields
    optics = {
        "nominal": {
            "exact": (exact["psf"][0], exact["vignetting"][0], heights["nominal"]),
            "surrogate": (psf_ns, vig_ns, h_train),
        },
        "end_to_end": {
            "exact": (exact["psf"][1], exact["vignetting"][1], heights["end_to_end"]),
            "surrogate": (psf_es, vig_es, h_train),
        },
    }
    cams = {"nominal": nom_cam, "end_to_end": cam}
    samples = heldout_streets(
        cfg.eval_scenes, cfg.crop_hw, exact["psf"].shape[-1] // 2, (task.level_min, task.level_max), frame
    )
    preds: dict[str, dict[str, list]] = {}
    reused_s = 0.0
    for who in cams:
        preds[who] = {}
        for kind in ("exact", "surrogate"):
            path = out / f"detections_{who}_{kind}.json"
            psf, vig, fh = optics[who][kind]
            key = _digest(psf, vig, fh, f_numbers[who], cams[who], len(samples))
            try:
                cached = json.loads(path.read_text())
            except (OSError, ValueError, RecursionError):
                cached = None
            if isinstance(cached, dict) and cached.get("key") == key:
                try:  # a damaged cache (hand-edited, cut short) is detected again, not a traceback
                    preds[who][kind] = _preds_from_json(cached["detections"])
                    reused_s += float(cached.get("wall_s", 0.0))
                    continue
                except (KeyError, TypeError, ValueError, RuntimeError):
                    pass
            t0 = time.perf_counter()
            fo = FixedOptics(psf, vig, fh, patch=cfg.patch, full_field_px=frame.full_field_px, f_number=f_numbers[who])
            ev_cam = DetectionCamera(Camera(fo, cams[who].sensor, cams[who].isp), cams[who].detector)
            preds[who][kind] = evaluate_detection(ev_cam, samples, progress, f"eval {who} ({kind} optics)")
            write_json_atomic(
                path,
                {
                    "key": key,
                    "wall_s": time.perf_counter() - t0,
                    "images": [s.name for s in samples],
                    "detections": _preds_json(preds[who][kind]),
                },
            )

    log("[4/4] mAP and its interval, lens export, checks, PSF grids, panels, reports")
    scores = {
        who: {kind: detection_scores(preds[who][kind], samples, task.dark) for kind in ("exact", "surrogate")}
        for who in cams
    }
    paired = paired_map(
        preds["nominal"]["exact"], preds["end_to_end"]["exact"], samples, cfg.bootstrap, cfg.seed, task.dark
    )
    fields_deg = [float(f) for f in sur.manifest["fields_deg"]]
    exported, checks = outputs.write_design_outputs(out, cfg, sur, nominal_values.numpy(), final_values.numpy(), exact)
    _detection_panels(out / "panels.png", samples, preds, optics, cams, f_numbers, cfg.patch, frame)
    reports = {who: write_report(Lens.load(out / "lens" / f"{who}.json"), out / "report" / who) for who in cams}

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
            "surrogate": {k: scores[who]["surrogate"][k] for k in ("map_50", "map", "dark")},
        }

    results = {
        "task": cfg.task,
        "description": task.description,
        "optimizer": cfg.optimizer,
        "budget": cfg.budget,
        "seed": cfg.seed,
        "optics_eval": "exact",
        "nominal": camera_summary("nominal"),
        "end_to_end": camera_summary("end_to_end"),
        "paired": paired,
        "lens_zmx": str(Path(exported["zmx"]).relative_to(out)),
        "lens_json": str(Path(exported["json"]).relative_to(out)),
        "design": {
            "parameters": sur.param_names,
            "nominal": [float(v) for v in nominal_values],
            "end_to_end": [float(v) for v in final_values],
            "checks": checks,
        },
        "surrogate_psf_rel_l1_per_field": {
            "fields_deg": fields_deg,
            "nominal": outputs.psf_rel_l1_per_field(psf_ns, exact["psf"][0]),
            "end_to_end": outputs.psf_rel_l1_per_field(psf_es, exact["psf"][1]),
        },
        "exact_psf_method": {"nominal": exact["methods"][0], "end_to_end": exact["methods"][1]},
        "exact_psf_energy_in_window": {
            "fields_deg": fields_deg,
            "window_px": int(exact["psf"].shape[-1]),
            "nominal": [float(e) for e in exact["energy_in_window"][0].min(axis=-1)],
            "end_to_end": [float(e) for e in exact["energy_in_window"][1].min(axis=-1)],
        },
        "held_out": {
            "n_images": len(samples),
            "n_objects": scores["nominal"]["exact"]["n_objects"],
            "n_objects_dark": scores["nominal"]["exact"]["dark"]["n_objects"],
            "size_px": list(cfg.crop_hw),
            "levels": [task.level_min, task.level_max],
        },
        "isp_hyperparameters": {"nominal": nom_cam.isp.hyperparameters(), "end_to_end": cam.isp.hyperparameters()},
        "training": {
            k: {kk: v[kk] for kk in ("steps", "wall_s", "final_loss", "cut_steps")}
            for k, v in (("end_to_end", e2e), ("nominal", nom))
        },
        "surrogate": cfg.surrogate,
    }
    _write_history(out / "history.csv", {"end_to_end": e2e["history"], "nominal": nom["history"]}, parts)
    _write_scenes(out / "metrics.csv", samples, preds)
    results["wall_s"] = e2e["wall_s"] + nom["wall_s"] + reused_s + (time.perf_counter() - t_eval)
    write_json_atomic(out / "results.json", results)
    return results


def _write_scenes(path: Path, samples, preds: dict) -> None:
    """Per held-out scene: where it lies, its light, its objects, and each camera's detections
    at score >= 0.3 under exact optics."""
    import csv

    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["image", "radius", "level", "n_objects", "n_dark", *(f"n_detections_{who}" for who in preds)])
        for i, s in enumerate(samples):
            w.writerow(
                [
                    s.name,
                    f"{s.radius:.4f}",
                    f"{s.level:.4f}",
                    len(s.target["labels"]),
                    int((s.object_light < 0.1).sum()),
                    *(int((preds[who]["exact"][i]["scores"] >= PANEL_SCORE).sum()) for who in preds),
                ]
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
    from torchvision.utils import draw_bounding_boxes

    from .. import color
    from ..scenes.street import CATEGORIES

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
            cam = DetectionCamera(Camera(fo, cams[who].sensor, cams[who].isp), cams[who].detector)
            img = cam.final_image(s.scene[None], s.offset_px, torch.Generator().manual_seed(int(s.noise_seed)))[0]
            p = preds[who]["exact"][i]
            keep = p["scores"] >= PANEL_SCORE
            imgs.append(boxed(img, p["boxes"][keep], p["labels"][keep], "cyan"))
        rows.append((f"{s.name} (r {s.radius:.2f}, {int((s.object_light < 0.1).sum())} in the dark)", imgs))
    outputs.save_panels(
        path,
        rows,
        [
            "scene (ideal, at sunlit exposure) + boxes",
            f"nominal f/{f_numbers['nominal']:.2f} + fine-tuned",
            f"end-to-end f/{f_numbers['end_to_end']:.2f}",
        ],
    )
