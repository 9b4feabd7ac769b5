"""The start detector tuned to the camera it starts in (``optix detect tune``).

The start detector learned street scenes as images (clean, and darkened with sensor noise:
``optix detect train``), not as the design run's camera delivers them at dusk: through the
nominal lens's PSFs, the sensor and the hardware ISP at Alg. 1's random draw of its
hyperparameters. Behind that camera it finds little (the item-4 detector: mAP@0.5 0.19 on the
held-out scenes, 0.002 in the dark, for seed 2's draw), so a design run's first updates teach
the processing the camera while the lens already moves on its gradient. The paper compares
against a detector and ISP fine-tuned "for the pipeline using the nominal optics on images
simulated with the same nominal optics" (Sec. 6.1). This builds that start: the nominal lens
(the engine's PSFs, fixed) and the sensor; the hardware ISP, from its default settings, and
the detector trained jointly on the task's loss (Alg. 1's joint steps: each block's Adam at
the design run's rate, ``lr_isp_params`` and ``lr_detector``) for ``steps`` steps of the task's
training batches (their own seed, apart from the design runs' 0, 1, 2), on the CPU.

The folder holds ``tune_state.pt`` (resumable: the same command continues), ``history.csv``,
``detector.pt`` (a detector checkpoint with the tuned ISP: ``detector = "DIR/detector.pt"`` and
``isp_init = "detector"`` in a design run's config file start both its cameras there) and ``tune.json``: the validation mAP of the
nominal camera with the start and the tuned detector (``tasks.detection.VALIDATION_STREETS``,
not the held-out scenes).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path

import torch

from .. import parallel
from ..errors import InputError
from ..io import claim_out_dir, write_json_atomic
from ..isp import params as hp
from ..tasks.detection import VALIDATION_STREETS, heldout_streets
from ..tasks.detector_train import load_detector, save_detector
from ..tasks.shipped_detectors import detector_file
from .build import make_optimizer, start_run
from .config import DesignConfig
from .detection import detection_scores, evaluate_detection
from .run import hooks_for
from .training import train, write_history

TUNE_SEED = 100  # the tuning's training stream (design runs use 0, 1, 2 by default)


def _read_record(path: Path) -> dict:
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        record = None
    if not isinstance(record, dict):
        raise InputError(f"{path} is damaged; remove the folder or choose another --out")
    return record


def _validation(cam, samples, task) -> dict:
    s = detection_scores(evaluate_detection(cam, samples), samples, task.dark)
    return {"map_50": s["map_50"], "map": s["map"], "dark_map_50": s["dark"]["map_50"]}


def tune_start_detector(
    cfg: DesignConfig, out: "str | Path", steps: int, *, scenes: int = 100, progress: bool = True, log=print
) -> dict:
    """Train the start detector of ``cfg`` (its ``detector``, else the bundled one) behind the
    nominal camera of ``cfg``'s space for ``steps`` steps; see the module's docstring."""
    if cfg.task != "detection":
        raise InputError(f"the start detector is tuned for the detection task, not {cfg.task}")
    cfg = dataclasses.replace(cfg, seed=TUNE_SEED, optimizer="alg1")  # joint steps, each block at its own rate
    out, task, frame, sur = start_run(cfg, out)
    hooks = hooks_for(cfg, "cpu")
    hooks.check(sur, parallel.Ranks())
    start_detector = detector_file(cfg.detector)
    _, start_ck = load_detector(start_detector)
    settings = {
        "detector": start_detector.name,
        "detector_sha256": hashlib.sha256(start_detector.read_bytes()).hexdigest(),
        "space": cfg.space,
        "steps": steps,
        "seed": TUNE_SEED,
        "lr_detector": cfg.lr_detector,
        "lr_isp_params": cfg.lr_isp_params,
        "isp_start": "defaults",
        "batch": cfg.batch,
        "crop": list(cfg.crop_hw),
        "validation_scenes": scenes,
    }
    record_path = out / "tune.json"
    if claim_out_dir(out, "detector tuning", marker=record_path.name):
        record = _read_record(record_path)
        if record.get("tuned_from") != settings:
            was = record.get("tuned_from") or {}
            detail = ", ".join(f"{k}: {was.get(k)!r} -> {v!r}" for k, v in settings.items() if was.get(k) != v)
            raise InputError(f"{out} was tuned with other settings ({detail}); use another --out or the same settings")
    else:
        record = {"tuned_from": settings}
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(record_path, record)
    probe = hooks.build_camera(sur, frame)  # a design run's camera: its nominal lens and exact optics
    nominal_values = probe.optics.base_values()
    surrogate_psfs = (None, None)  # exact optics: the engine's PSFs of the nominal lens
    if cfg.optics != "exact":
        with torch.no_grad():
            surrogate_psfs = sur.psfs(nominal_values, check=False)
    fixed = hooks.nominal_optics(probe, sur, nominal_values, surrogate_psfs, frame)
    cam = hooks.build_camera(sur, frame, fixed_optics=fixed)
    with torch.no_grad():  # the ISP starts at its default settings (a vendor's tuning), not a random draw
        cam.isp.logit.copy_(torch.logit(torch.as_tensor(hp.to_unit(hp.defaults()), dtype=torch.float32), eps=1e-6))
    samples = heldout_streets(
        scenes, cfg.crop_hw, fixed.psf.shape[-1] // 2, (task.level_min, task.level_max), frame, start=VALIDATION_STREETS
    )
    if "start" not in record and scenes and not (out / "tune_state.pt").is_file():
        t0 = time.perf_counter()
        record["start"] = _validation(cam, samples, task)
        write_json_atomic(record_path, record)
        log(
            f"start detector behind the nominal camera: validation mAP@0.5 {record['start']['map_50']:.3f} "
            f"({time.perf_counter() - t0:.0f} s)"
        )
    # joint steps of the ISP's and the detector's Adam, each at the design run's rate
    opt = make_optimizer(dataclasses.replace(cfg, n_cycles=0, n_finetune=steps), cam, "nominal")
    res = train(
        cfg,
        cam,
        opt,
        out,
        "tune",
        loss_at=hooks.loss_at(cam, frame, parallel.Ranks()),
        parts=hooks.loss_parts,
        progress=progress,
        log=log,
        frame=frame,
    )
    write_history(out / "history.csv", {"tune": res["history"]}, hooks.loss_parts)
    if scenes:
        record["tuned"] = _validation(cam, samples, task)
    config = {**start_ck["config"], "image_size": list(cfg.crop_hw)}
    tuned_from = {**settings, "nominal_f_number": hooks.f_number(nominal_values)}
    isp_unit = [float(v) for v in cam.isp.unit().detach().cpu()]
    save_detector(
        out / "detector.pt",
        cam.detector,
        config,
        step=res["steps"],
        wall_s=res["wall_s"],
        tuned=tuned_from,
        isp_unit=isp_unit,
    )
    record["isp_hyperparameters"] = cam.isp.hyperparameters()
    record |= {"nominal_f_number": tuned_from["nominal_f_number"], "wall_s": res["wall_s"]}
    write_json_atomic(record_path, record)
    if scenes:
        log(f"tuned detector behind the nominal camera: validation mAP@0.5 {record['tuned']['map_50']:.3f}")
    return record
