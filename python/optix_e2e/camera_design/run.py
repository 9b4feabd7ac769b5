"""An end-to-end design run (`optix design TASK --out DIR`): the paper's Sec. 6.1 experiment,
the same skeleton for every task (the task's part is a plugin: task_hooks.py).

1. Check everything, then claim the run folder (config.json; a folder of another run or
   other files is refused before a byte is written).
2. Train two cameras with the same seed, batches, sensor-noise draws and number of steps
   (training.py; checkpointed, a killed run resumes on the same path):
   * ``end_to_end``: lens (surrogate or exact optics) and processing (and the task's network)
     together, by Alg. 1 or vanilla Adam, the manufacturability guard after each lens step;
   * ``nominal``: the lens fixed at the nominal design, the processing fine-tuned with the same
     task loss (the paper's fair comparison), each processing block updated as many times as
     in the end-to-end run (build.make_optimizer);
   * ``ideal_lens`` (the image-quality tasks: TaskHooks.ideal_optics): the same as ``nominal``
     behind a lens that blurs nothing (build.delta_lens): the ceiling.
3. Compute both lenses' exact PSFs with the engine and evaluate both cameras on held-out data
   under them (and, for reference, under the surrogate's), and the task's further baselines
   (the ideal lens; ``nominal_untuned``, the nominal lens behind the processing before any
   fine-tuning: TaskHooks.untuned_camera); evaluations are cached (eval_cache.py).
4. Write the outputs: both lenses (.zmx, .json, reports, PSF grids), panels, history.csv,
   lens_path.csv (the lens after each lens step), metrics.csv and results.json.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import torch

from .. import parallel
from ..io import tensorboard_writer, write_json_atomic
from ..lens import Lens
from ..lens_design.report import write_report
from ..scenes.corpus import PhotoCorpus
from ..surrogate.ground_truth import exact_optics
from ..tasks import plugin
from . import outputs
from .build import design_field_heights, lens_step_scale, make_optimizer, start_record, start_run
from .config import DesignConfig, check_run_dir, resume_settings
from .memory import check_memory
from .task_hooks import RunState, TaskHooks
from .training import lens_travel, train, write_history, write_lens_path

WHO = ("nominal", "end_to_end")


def hooks_for(cfg: DesignConfig, device: "torch.device | str" = "cpu") -> TaskHooks:
    """The task's hooks (its plugin's, tasks/registry.py), its cameras on ``device``."""
    return plugin(cfg.task).hooks_class()(cfg, device)


def summary_lines(cfg: DesignConfig, results: dict) -> list[str]:
    """What ``optix design`` prints about a run's results: the task's lines, read from the
    results alone (no second set of hooks: those resolve the optics model and scan --images)."""
    return plugin(cfg.task).hooks_class().summary_lines(results)


def claim_run_dir(out: Path, cfg: DesignConfig, ranks: parallel.Ranks, progress: bool, log):
    """Check that the batch splits over the ranks, then rank 0 checks or creates the run
    directory (config.json) while the others wait. Returns this rank's (progress, log,
    TensorBoard writer): rank 0's as given with a writer into out/tb, the others' silent
    with none."""
    parallel.batch_slice(cfg.batch, ranks)
    if ranks.is_main:
        check_run_dir(out, cfg)
    parallel.barrier(ranks)
    if not ranks.is_main:
        return False, (lambda m: None), None
    return progress, log, tensorboard_writer(out / "tb")


def run_design(
    cfg: DesignConfig,
    out: "str | Path",
    *,
    given: "frozenset[str] | None" = None,
    progress: bool = True,
    log=print,
    test_photos=(),
) -> dict | None:
    """The whole run; returns the results (also written to out/results.json). Where ``out``
    holds a run already, the settings not named in ``given`` (config.load_config; None: every
    setting given) are the folder's, and the run resumes as it was made. Under torchrun
    (``torchrun --nproc_per_node N -m optix_e2e design ...``) the N processes share each
    training batch (optix_e2e.parallel); rank 0 alone evaluates and writes, and the other
    ranks return None once the trainings are done."""
    ranks = parallel.setup(cfg.device)  # cfg.device: --device (torchrun: gloo on the CPU, NCCL on CUDA)
    kept = resume_settings(Path(out), cfg, given)  # an existing run: what the user did not give, the folder's
    if kept != cfg and ranks.is_main:
        taken = [f"{k} = {getattr(kept, k)!r}" for k in kept.to_json() if getattr(kept, k) != getattr(cfg, k)]
        log(f"{out} resumes with its own {', '.join(taken)} (config.json; give a setting to hold the run to it)")
    cfg = kept
    # the untouched test split (docs/test-split.md), checked before anything runs; not a setting of
    # the run: evaluated when asked for, on a finished run too (its trainings and evaluations reused)
    test_corpus = PhotoCorpus(test_photos, "test") if test_photos and ranks.is_main else None
    out, _, frame, sur = start_run(cfg, out)
    sur.to(ranks.device)  # every camera's optics (and a hybrid run's copy) start from it there
    hooks = hooks_for(cfg, ranks.device)
    # everything the run needs is checked before the run directory is claimed
    hooks.check(sur, ranks)
    margin = hooks.build_camera(sur, frame).margin
    check_memory(cfg, margin, str(ranks.device))  # a batch that cannot fit: refused now, not minutes in
    progress, log, writer = claim_run_dir(out, cfg, ranks, progress, log)
    common = dict(progress=progress, writer=writer, frame=frame, log=log, ranks=ranks, parts=hooks.loss_parts)
    try:
        log(f"[1/4] {hooks.describe()}")
        camera = hooks.build_camera(sur, frame, trained=True)
        start_values = camera.optics.values().detach().clone()  # before any step (a resume loads later)
        lens_scale = lens_step_scale(cfg, camera, start_values)  # from the start: a resume scales alike
        monitor = hooks.monitor(camera, writer, log)
        e2e = train(
            cfg,
            camera,
            make_optimizer(cfg, camera, cfg.optimizer),
            out,
            "end_to_end",
            loss_at=hooks.loss_at(camera, frame, ranks),
            folder=hooks.folder,
            corpus=hooks.corpus,
            monitor=monitor if ranks.is_main else None,  # surrogate optics: it only measures
            lens_scale=lens_scale,
            **common,
        )
        nominal_values = camera.optics.base_values()
        psf_ns = vig_ns = None  # no network on this space's terms: the hooks use the engine's (exact optics)
        if sur.has_network:
            with torch.no_grad():
                psf_ns, vig_ns = sur.psfs(nominal_values, check=False)
        fixed = hooks.nominal_optics(camera, sur, nominal_values, (psf_ns, vig_ns), frame)
        nominal = hooks.build_camera(sur, frame, fixed_optics=fixed)
        nom_opt = make_optimizer(cfg, nominal, "nominal")
        updates = ", ".join(f"{k} {v}" for k, v in nom_opt.scheduled_updates().items())
        log(
            f"[2/4] nominal lens + processing fine-tuned, the end-to-end run's updates per processing block ({updates})"
        )
        nom = train(
            cfg,
            nominal,
            nom_opt,
            out,
            "nominal",
            loss_at=hooks.loss_at(nominal, frame, ranks),
            folder=hooks.folder,
            corpus=hooks.corpus,
            **common,
        )
        # the ceiling (image-quality tasks): the baseline's processing fine-tuned on the same budget
        # behind a lens that blurs nothing; a run folder made before it trains it on its next call
        ideal = ideal_run = None
        ideal_optics = hooks.ideal_optics(sur, nominal_values, frame)
        if ideal_optics is not None:
            ideal = hooks.build_camera(sur, frame, fixed_optics=ideal_optics)
            ideal_opt = make_optimizer(cfg, ideal, "nominal")
            log(f"[2/4] ideal lens (a one-pixel PSF, the nominal's shading) + processing fine-tuned ({updates})")
            ideal_run = train(
                cfg,
                ideal,
                ideal_opt,
                out,
                "ideal_lens",
                loss_at=hooks.loss_at(ideal, frame, ranks),
                folder=hooks.folder,
                corpus=hooks.corpus,
                **common,
            )
    finally:
        if writer is not None:
            writer.close()
    if not ranks.is_main:
        return None

    t_eval = time.perf_counter()
    log("[3/4] exact PSFs of both lenses (engine) and held-out evaluation")
    final_values = camera.optics.values().detach()
    values = {"nominal": nominal_values, "end_to_end": final_values}
    f_numbers = {who: hooks.f_number(v) for who, v in values.items()}
    exact = exact_optics(
        sur, torch.stack([nominal_values, final_values]).double().cpu().numpy(), fallback=hooks.exact_fallback
    )
    psf_es = vig_es = None
    if sur.has_network:
        with torch.no_grad():  # the shipped surrogate at the final design (a hybrid run's refined model: optics_model)
            psf_es, vig_es = sur.psfs(final_values, check=False)
    # field positions: each design's own chief-ray heights under exact optics, the nominal's
    # (what training used) under the surrogate's (None: no network on these terms)
    h_train = camera.optics.render_fields
    surrogate_psfs = {"nominal": (psf_ns, vig_ns), "end_to_end": (psf_es, vig_es)}
    optics = {
        who: {
            "exact": (
                exact["psf"][i],
                exact["vignetting"][i],
                design_field_heights(sur, values[who].cpu().numpy(), exact["image_distance"][i]),
            ),
            "surrogate": (*surrogate_psfs[who], h_train) if sur.has_network else None,
        }
        for i, who in enumerate(WHO)
    }
    cams = {"nominal": nominal, "end_to_end": camera}
    untuned = hooks.untuned_camera(sur, frame, fixed)  # the processing before any fine-tuning
    if untuned is not None:
        cams["nominal_untuned"] = untuned
    if ideal is not None:
        cams["ideal_lens"] = ideal
    state = RunState(cfg, out, frame, sur, cams, optics, f_numbers, exact, progress)
    state.evaluation, reused_s = hooks.evaluate(state)

    log("[4/4] lens export, checks, PSF grids, panels, reports")
    exported, checks = outputs.write_design_outputs(
        out, cfg, sur, nominal_values.cpu().numpy(), final_values.cpu().numpy(), exact
    )
    hooks.panels(state, out / "panels.png")
    state.reports = {who: write_report(Lens.load(out / "lens" / f"{who}.json"), out / "report" / who) for who in WHO}
    runs = {"end_to_end": e2e, "nominal": nom, "ideal_lens": ideal_run}
    lens = LensRecord(nominal_values, start_values, final_values, lens_scale, exported, checks)
    results = results_document(state, hooks, ranks, runs, lens, (psf_ns, psf_es), monitor)
    if test_corpus is not None:
        baseline = results.get("baseline", {}).get("camera", "nominal")
        results["test_split"] = hooks.test_split(state, test_corpus, baseline)
    write_history(out / "history.csv", {k: v["history"] for k, v in runs.items() if v is not None}, hooks.loss_parts)
    write_lens_path(out / "lens_path.csv", e2e["history"], sur.param_names, start_values.tolist())
    hooks.write_tables(state)
    # training (every camera trained, across resumes) + exact PSFs, evaluation and outputs of this call
    # + the evaluations it reused from an earlier one
    trained_s = sum(v["wall_s"] for v in runs.values() if v is not None)
    results["wall_s"] = trained_s + reused_s + (time.perf_counter() - t_eval)
    write_json_atomic(out / "results.json", results)
    return results


@dataclass(frozen=True)
class LensRecord:
    """The lens of a run: its nominal, start and final values, the factors on its steps (None:
    Adam's own), the exported files and their checks (outputs.write_design_outputs)."""

    nominal: torch.Tensor
    start: torch.Tensor
    final: torch.Tensor
    scale: "torch.Tensor | None"
    exported: dict
    checks: dict


#: what results.json's ``training`` keeps of each camera's training
TRAINING_KEYS = ("steps", "updates", "wall_s", "final_loss", "lens_steps", "cut_steps", "guard", "barrier_steps")


def results_document(
    run: RunState,
    hooks: TaskHooks,
    ranks: parallel.Ranks,
    trainings: dict,
    lens: LensRecord,
    surrogate_psfs,
    monitor,
) -> dict:
    """results.json of a design run (docs/e2e.md, "results.json"): the task's figures
    (TaskHooks.summarize, held_out, extra), the lens, the optics models' agreement, the trainings;
    ``surrogate_psfs`` the network's PSFs of the nominal and the final lens (None, None: no network)."""
    cfg, sur, out, exact = run.cfg, run.sur, run.out, run.exact
    psf_ns, psf_es = surrogate_psfs
    fields_deg = [float(f) for f in sur.manifest["fields_deg"]]
    camera = run.cams["end_to_end"]
    return {
        "task": cfg.task,
        "description": hooks.task.description,
        "optimizer": cfg.optimizer,
        "budget": cfg.budget,
        "seed": cfg.seed,
        "device": str(ranks.device),  # where this call ran (a resumed run may have trained elsewhere)
        "precision": cfg.precision,  # the networks' arithmetic (optix_e2e.precision)
        "optics_eval": "exact",
        **hooks.summarize(run),
        "lens_zmx": str(Path(lens.exported["zmx"]).relative_to(out)),
        "lens_json": str(Path(lens.exported["json"]).relative_to(out)),
        "design": {
            "parameters": sur.param_names,
            "nominal": [float(v) for v in lens.nominal],
            "start": [float(v) for v in lens.start],
            # each parameter's factor on Adam's steps in u (lens_steps = "range"), null: none
            "step_scale": None if lens.scale is None else lens.scale.tolist(),
            "end_to_end": [float(v) for v in lens.final],
            # how far the lens moved from its start, as fractions of each range (lens_path.csv: each step)
            "travel": lens_travel(
                sur.param_names,
                camera.optics.lo.tolist(),
                camera.optics.hi.tolist(),
                lens.start.tolist(),
                trainings["end_to_end"]["history"],
            ),
            "checks": lens.checks,
        },
        "surrogate_psf_rel_l1_per_field": {
            "fields_deg": fields_deg,
            "nominal": outputs.psf_rel_l1_per_field(psf_ns, exact["psf"][0]),
            "end_to_end": outputs.psf_rel_l1_per_field(psf_es, exact["psf"][1]),
        }
        if sur.has_network
        else {"fields_deg": fields_deg, "nominal": None, "end_to_end": None, "no_network": sur.no_network_why},
        "exact_psf_method": {"nominal": exact["methods"][0], "end_to_end": exact["methods"][1]},
        # the exact PSFs are normalized over their window: how much of each field's flux that
        # window holds (worst channel), for both lenses
        "exact_psf_energy_in_window": {
            "fields_deg": fields_deg,
            "window_px": int(exact["psf"].shape[-1]),
            "nominal": [float(e) for e in exact["energy_in_window"][0].min(axis=-1)],
            "end_to_end": [float(e) for e in exact["energy_in_window"][1].min(axis=-1)],
        },
        "held_out": hooks.held_out(run),
        "training": {k: {kk: v[kk] for kk in TRAINING_KEYS} for k, v in trainings.items() if v is not None},
        "surrogate": cfg.surrogate,
        "start": start_record(cfg),
        # the space the lens moved in: its ranges, and whether the network was trained on it
        "space": {
            "source": sur.manifest["space"].get("source"),
            "surrogates_own": "trained_space" not in sur.manifest,
            "ranges": {p["name"]: [p["min"], p["max"]] for p in sur.manifest["space"]["parameters"]},
        },
        **hooks.extra(run, monitor, trainings["end_to_end"]),
    }
