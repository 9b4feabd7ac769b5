"""An end-to-end design run (`optix design TASK --out DIR`): the paper's Sec. 6.1 experiment.

Two trainings with the same seed, batches, sensor-noise draws and number of steps:

* ``end_to_end``: lens (surrogate optics) and processing together, by Alg. 1 or vanilla Adam;
* ``nominal``: the lens fixed at the nominal design, the processing fine-tuned with the same
  task loss (the paper's fair comparison), the same number of steps;

then both cameras are evaluated on the held-out set under the exact engine's PSFs of their
lens (and, for reference, under the surrogate's), see optimize/evaluate.py.

Resuming: each training checkpoints its parameters, optimizer state and step (atomically)
every ``checkpoint_every`` steps; batches and noise are functions of (seed, step), so a run
killed at any point and started again with the same command continues on the same path.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .. import parallel
from ..camera import (
    Camera,
    FixedOptics,
    HardwareISPStage,
    PerfectOptics,
    SensorStage,
    SoftwareISPStage,
    calibrated_preset,
)
from ..isp import params as hp
from ..isp.proxy import ISPProxy
from ..isp.software import SoftwareISP
from ..lens import Lens
from ..optics import DifferentiableOptics
from ..io import write_json_atomic
from ..io import save_atomic
from ..surrogate.checkpoint import OpticsSurrogate
from ..surrogate.exact import exact_optics
from ..tasks import SensorFrame, TaskLoss, get_task, training_batch
from ..tasks.scenes import POSITIONS
from ..torchfile import DAMAGED_STATE_ERRORS, load_plain
from .alg1 import Block, ProximalCompositional, Vanilla
from .config import DesignConfig

LOSS_PARTS = ("l1", "lpips")  # the image-quality tasks' loss terms, in history.csv


def history_keys(parts: tuple[str, ...] = LOSS_PARTS) -> tuple[str, ...]:
    return ("step", "phase", "block", "loss", "prox", *parts, "cut", "optics", "seconds")


SOFTWARE_ISP = Path(__file__).resolve().parent.parent / "isp" / "bundled" / "software_isp.pt"


def load_surrogate(spec: str, pixel_um: float | None = None) -> OpticsSurrogate:
    """The optics surrogate, checked to render at the sensor's pitch (``pixel_um``)."""
    sur = OpticsSurrogate.load(spec)
    if pixel_um is not None:
        pitch = float(sur.manifest.get("settings", {}).get("sensor_pixel_um", float("nan"))) * sur.bin
        if sur.psf_kind != "psf_sensor" or not math.isclose(pitch, pixel_um, rel_tol=1e-6):
            raise ValueError(
                f"surrogate {spec}: its PSFs are {sur.psf_kind} at {pitch} um per pixel; the camera "
                f"renders at the sensor's {pixel_um} um (train it on psf_sensor, --bin 1)"
            )
    return sur


def base_lens_f_number(sur: OpticsSurrogate) -> float:
    from ..dataset.manifest import space_and_base

    _, base = space_and_base(sur.manifest)
    return float(base.paraxial()["f_number"])


class Manufacturable:
    """The dataset's manufacturability limits (centre and edge thickness, air gaps, BFD; the
    space file's [constraints]) as a check on parameter values: ``problems(values)`` lists the
    violated ones (empty: manufacturable). Edge thicknesses at the ray footprint, the image
    plane at the base lens's distance (the BFD limit is far from binding in these spaces)."""

    def __init__(self, manifest: dict):
        from ..dataset.manifest import space_and_base
        from ..design.sampling import Limits

        self.manifest = manifest
        self.limits = Limits.from_dict(manifest.get("sampling_summary", {}).get("limits"))
        _, base = space_and_base(manifest)
        self.image_distance = float(base.data["surfaces"][-1]["thickness"])
        self.checks = 0

    def problems(self, values) -> list[str]:
        from ..design.sampling import apertures, check_design
        from .outputs import design_lens

        self.checks += 1
        d = design_lens(self.manifest, np.asarray(values, np.float64), self.image_distance)
        try:
            return check_design(d, apertures(Lens(d, source="<design>")), self.limits)
        except Exception as err:  # a design the engine cannot trace is not manufacturable either
            return [f"untraceable: {' '.join(str(err).split())}"]

    def margins(self, values) -> np.ndarray:
        """Each limit's value minus its bound (mm; >= 0 where met), in a fixed order."""
        from ..design.optimizer import Constraints
        from ..design.sampling import apertures
        from .outputs import design_lens

        self.checks += 1
        d = design_lens(self.manifest, np.asarray(values, np.float64), self.image_distance)
        lim = self.limits
        rows = Constraints(
            min_center=lim.min_center, min_edge=lim.min_edge, min_air_gap=lim.min_air_gap, min_bfd=lim.min_bfd
        ).evaluate(d, {}, apertures(Lens(d, source="<design>")))
        return np.array([r["value"] - r["limit"] for r in rows if "limit" in r])


def _values(optics: DifferentiableOptics, u: torch.Tensor) -> np.ndarray:
    return (optics.lo + (optics.hi - optics.lo) * torch.sigmoid(u)).detach().double().numpy()


def project_step(
    optics: DifferentiableOptics,
    u_prev: torch.Tensor,
    step: torch.Tensor,
    guard: Manufacturable,
    h: float = 1e-3,
    near_mm: float = 0.05,
) -> torch.Tensor:
    """The step with its components across the limits it would break removed: the limits
    within ``near_mm`` of their bound at u_prev, linearized by forward differences in u
    (one margin evaluation per parameter), and the step projected onto {J d >= -m}
    (least-distance projection, active set by nonnegative least squares). Where the engine
    cannot trace one of those points, the step is returned unchanged and the caller cuts it
    back along itself (``problems`` calls such a point unmanufacturable)."""
    from scipy.optimize import nnls

    try:
        m0 = guard.margins(_values(optics, u_prev))
        m1 = guard.margins(_values(optics, u_prev + step))
        active = np.flatnonzero((m0 < near_mm) | (m1 < 0))
        if active.size == 0:
            return step
        jac = np.empty((active.size, u_prev.numel()))
        for k in range(u_prev.numel()):
            du = torch.zeros_like(u_prev)
            du[k] = h
            jac[:, k] = (guard.margins(_values(optics, u_prev + du))[active] - m0[active]) / h
    except Exception:  # untraceable (a ray misses a surface, surfaces cross): no linearization here
        return step
    d = step.double().numpy()
    # min |d' - d|^2 s.t. J d' >= -m0: d' = d + J^T lam, lam >= 0 minimizing |J J^T lam - (-m0 - J d)|
    lam, _ = nnls(jac @ jac.T + 1e-12 * np.eye(active.size), np.maximum(-m0[active] - jac @ d, 0.0))
    return torch.as_tensor(d + jac.T @ lam, dtype=step.dtype)


def keep_manufacturable(
    optics: DifferentiableOptics, u_prev: torch.Tensor, guard: Manufacturable, iters: int = 12, project: bool = True
) -> bool:
    """After an optimizer step: if the new lens parameters break a manufacturability limit,
    the step is projected along the limits it leans across (``project_step``: the lens slides
    along an active limit instead of stopping at it), then, if the projected step still
    breaks one (the limits curve), cut back along it to the farthest manufacturable point
    (bisection; the previous point is manufacturable). Returns True when the step changed."""
    u_new = optics.u.detach().clone()
    if not guard.problems(optics.values().detach().numpy()):
        return False
    if project:
        u_new = u_prev + project_step(optics, u_prev, u_new - u_prev, guard)
        with torch.no_grad():
            optics.u.copy_(u_new)
        if not guard.problems(optics.values().detach().numpy()):
            return True
    lo, hi = 0.0, 1.0
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        with torch.no_grad():
            optics.u.copy_(u_prev + mid * (u_new - u_prev))
        if guard.problems(optics.values().detach().numpy()):
            hi = mid
        else:
            lo = mid
    with torch.no_grad():
        optics.u.copy_(u_prev + lo * (u_new - u_prev))
    return True


def initial_optics_values(cfg: DesignConfig, optics: DifferentiableOptics) -> torch.Tensor:
    """The nominal design, or a uniform draw inside the space's ranges (seeded), redrawn until
    it is manufacturable (as the dataset's designs are)."""
    if cfg.optics_init == "nominal":
        return optics.base_values()
    rng = np.random.default_rng([3, int(cfg.seed)])  # stream tag 3: optics init (1: batches, 2: ISP init)
    guard = Manufacturable(optics.surrogate.manifest) if optics.surrogate.manifest else None
    for _ in range(1000):
        u = torch.as_tensor(rng.random(len(optics.lo)), dtype=torch.float32)
        v = optics.lo + (optics.hi - optics.lo) * (0.02 + 0.96 * u)
        if guard is None or not guard.problems(v.numpy()):
            return v
    raise ValueError("no manufacturable design in 1000 uniform draws of the space")


def design_field_heights(sur: OpticsSurrogate, values, image_distance: float) -> torch.Tensor:
    """The surrogate's fields placed where the design ``values`` images them, its image plane
    at ``image_distance`` (the chief rays' heights as fractions of the full field)."""
    from ..camera.stages import image_height_fractions
    from .outputs import design_lens

    return image_height_fractions(design_lens(sur.manifest, values, image_distance), sur.fields_deg)


def nominal_field_heights(sur: OpticsSurrogate) -> torch.Tensor:
    """The surrogate's fields placed where the nominal lens images them (refocused as its
    dataset was): the renderer's field positions in training."""
    from ..dataset.manifest import space_and_base

    if not sur.manifest:
        return sur.fields
    space, base = space_and_base(sur.manifest)
    return design_field_heights(sur, space.values(base.data), float(base.data["surfaces"][-1]["thickness"]))


def initial_isp_unit(cfg: DesignConfig) -> torch.Tensor:
    """Alg. 1's initialization of P_ISP: uniform random over the ranges (seeded)."""
    rng = np.random.default_rng([2, int(cfg.seed)])
    return torch.as_tensor(hp.to_unit(hp.sample(rng)), dtype=torch.float32)


def build_camera(
    cfg: DesignConfig,
    sur: OpticsSurrogate,
    *,
    fixed_optics: FixedOptics | None = None,
    frame: SensorFrame = SensorFrame(),
    own_surrogate: bool = False,
) -> Camera:
    """The camera at its initialization: the same for Alg. 1, vanilla and the nominal baseline
    (apart from the optics, fixed at the nominal for the latter). ``own_surrogate``: the optics
    get a copy of the surrogate (a hybrid run refines its own)."""
    import copy

    task = get_task(cfg.task)
    if fixed_optics is None:
        optics = DifferentiableOptics(
            copy.deepcopy(sur) if own_surrogate else sur, patch=cfg.patch, full_field_px=frame.full_field_px
        )
        optics.set_values(initial_optics_values(cfg, optics))
        optics.render_fields = nominal_field_heights(sur)
        optics.use_fields(cfg.fields)
    else:
        optics = fixed_optics
    preset = calibrated_preset("imx249", base_lens_f_number(sur), task.exposure_factor, task.gain_factor)
    sensor = SensorStage(preset)
    if task.isp == "software":
        path = Path(cfg.software_isp) if cfg.software_isp else SOFTWARE_ISP
        if not path.is_file():
            raise FileNotFoundError(f"the pre-trained software ISP is missing: {path}")
        isp = SoftwareISPStage(SoftwareISP.load(path).train(), preset)
    else:
        isp = HardwareISPStage(ISPProxy.load(), initial_isp_unit(cfg), preset.cfa, preset.adc_bits)
    return Camera(optics, sensor, isp)


BLOCK_SETTINGS = {
    "optics": ("lr_optics", "steps_optics", "beta_optics"),
    "isp": (None, "steps_isp", "beta_isp"),
    "detector": ("lr_detector", "steps_detector", "beta_detector"),
}


def make_optimizer(cfg: DesignConfig, camera, kind: str):
    """Alg. 1 or vanilla over the camera's blocks (optics, ISP, and the detection task's
    detector); the nominal baseline ("nominal") takes the same number of steps on its
    processing blocks together (each with its own optimizer and learning rate)."""
    task = get_task(cfg.task)
    blocks = []
    for name, params in camera.blocks().items():
        lr_key, steps_key, beta_key = BLOCK_SETTINGS[name]
        if name == "isp":
            lr = cfg.lr_isp_net if task.isp == "software" else cfg.lr_isp_params
        else:
            lr = getattr(cfg, lr_key)
        # the prox term in range-normalized units where the block is a sigmoid-reparameterized vector
        coords = torch.sigmoid if name == "optics" or (name == "isp" and task.isp == "hardware") else None
        blocks.append(Block(name, params, lr, getattr(cfg, steps_key), getattr(cfg, beta_key), coords))
    if kind == "nominal":
        return ProximalCompositional(
            [Block(b.name, b.params, b.lr, 1, 0.0) for b in blocks], n_cycles=0, n_finetune=cfg.total_steps
        )
    if kind == "vanilla":
        return Vanilla(blocks, cfg.lr_vanilla, cfg.total_steps)
    return ProximalCompositional(blocks, cfg.n_cycles, cfg.n_finetune)


def _save_state(path: Path, camera: Camera, opt, wall_s: float, history: list, monitor=None) -> None:
    save_atomic(
        {
            "format": "optix-design-state/1",
            "camera": camera.state_dict(),
            "optimizer": opt.state_dict(),
            "wall_s": wall_s,
            "history": history,
            "monitor": monitor.state_dict() if monitor is not None else None,
        },
        path,
    )


def _load_state(path: Path, camera: Camera, opt, monitor=None) -> tuple[float, list]:
    from .hybrid import OpticsModeMismatch

    st = load_plain(path, "design checkpoint")
    if not isinstance(st, dict) or st.get("format") != "optix-design-state/1":
        raise ValueError(f"{path}: not a design checkpoint (format optix-design-state/1)")
    try:
        camera.load_state_dict(st["camera"])
        opt.load_state_dict(st["optimizer"])
        wall_s, history = float(st["wall_s"]), list(st["history"])
        if not 0 <= opt.t <= opt.total_steps:
            raise ValueError(f"step {opt.t} outside this run's 0..{opt.total_steps}")
        if not (math.isfinite(wall_s) and wall_s >= 0):
            raise ValueError(f"wall_s {wall_s}")
        if monitor is not None and st.get("monitor") is not None:
            monitor.load_state_dict(st["monitor"])
    except OpticsModeMismatch:
        raise  # its own message: the run's optics model differs, the checkpoint is fine
    except DAMAGED_STATE_ERRORS as err:
        raise ValueError(
            f"{path}: damaged design checkpoint ({type(err).__name__}: {' '.join(str(err).split())}); "
            f"remove it to restart that training"
        ) from None
    return wall_s, history


def noise_generator(seed: int, t: int, ranks: parallel.Ranks = parallel.Ranks()) -> torch.Generator:
    """Step t's sensor-noise stream (stream tag 4); under torchrun each rank draws its own."""
    key = [4, int(seed), int(t)] + ([ranks.rank, ranks.world] if ranks.distributed else [])
    return torch.Generator().manual_seed(int(np.random.SeedSequence(key).generate_state(1)[0]))


def train(
    cfg: DesignConfig,
    camera: Camera,
    opt,
    out: Path,
    name: str,
    *,
    progress: bool = True,
    writer=None,
    frame: SensorFrame = SensorFrame(),
    folder=None,
    on_step=None,
    log=None,
    loss_at=None,
    parts: tuple[str, ...] = LOSS_PARTS,
    monitor=None,
    ranks: parallel.Ranks = parallel.Ranks(),
) -> dict:
    """Run ``opt`` to its last step on the task loss, checkpointing into out/{name}_state.pt.
    ``loss_at(t, generator)`` -> (loss, {part: value}) is step t's loss (default: the
    image-quality task's on ``training_batch``); ``parts`` name the values it reports.
    ``monitor``: an optimize.hybrid.OpticsMonitor checking the optics model along the way
    (before the first step, every ``check_every`` steps and after the last).
    ``ranks``: under torchrun, each rank computes its slice of every batch (a ``loss_at`` given
    here must do so too), the gradients are averaged before each step, rank 0 writes."""
    task = get_task(cfg.task)
    state_path = out / f"{name}_state.pt"
    wall_s, history = 0.0, []
    if state_path.is_file():
        wall_s, history = _load_state(state_path, camera, opt, monitor)
        if log is not None and ranks.is_main:
            log(f"{name}: resuming at step {opt.t} of {opt.total_steps} ({state_path.name})")
    ran = opt.t < opt.total_steps
    if ranks.distributed:
        parallel.broadcast_params(camera.parameters(), ranks)  # one starting point, whatever each rank read
        opt.reduce = lambda params, loss, info: parallel.average_step(ranks, params, loss, info)
        progress = progress and ranks.is_main
    if loss_at is None:
        loss_mod = TaskLoss(task)
        part = parallel.batch_slice(cfg.batch, ranks)

        def loss_at(t, gen):
            batch = training_batch(cfg.seed, t, cfg.batch, cfg.crop, m, (task.level_min, task.level_max), frame, folder)
            out_img, _ = camera(batch.scene[part], batch.offset_px, gen)
            return loss_mod(out_img, batch.target[part])

    optics = camera.optics if isinstance(camera.optics, DifferentiableOptics) else None
    guard = Manufacturable(optics.surrogate.manifest) if optics is not None and optics.surrogate.manifest else None
    camera.train()
    m = camera.margin
    t_start = time.perf_counter()
    bar = tqdm(
        total=opt.total_steps,
        initial=opt.t,
        desc=f"{name} ({opt.kind})",
        unit="step",
        disable=not progress,
        leave=False,
    )
    if monitor is not None and opt.t == 0 and not monitor.checks:
        monitor.check(0)
    while opt.t < opt.total_steps:
        t = opt.t
        gen = noise_generator(cfg.seed, t, ranks)

        def loss_fn():
            return loss_at(t, gen)

        t0 = time.perf_counter()
        u_prev = optics.u.detach().clone() if guard is not None else None
        backend = optics.backend if optics is not None else "fixed"
        info = opt.step(loss_fn)
        hint = "lower the learning rates (lr_optics, lr_isp_net, lr_isp_params, lr_detector) in another --out"
        parallel.stop_if_diverged(opt.t, state_path, hint, loss=info["loss"])
        info["optics"] = backend
        # the paper enforces its limits on every lens: a step that breaks one is cut back
        info["cut"] = int(
            guard is not None and info["block"] in ("optics", "all") and keep_manufacturable(optics, u_prev, guard)
        )
        info["seconds"] = time.perf_counter() - t0
        history.append({k: info[k] for k in history_keys(parts)})
        if writer is not None:
            for k in ("loss", *parts):
                writer.add_scalar(f"{name}/{k}", info[k], info["step"])
            if info["prox"]:
                writer.add_scalar(f"{name}/prox", info["prox"], info["step"])
        if monitor is not None and monitor.due(opt.t, opt.total_steps):
            monitor.check(opt.t, final=opt.t == opt.total_steps)
        if on_step is not None:
            on_step(info, camera)
        bar.update(1)
        bar.set_postfix(loss=f"{info['loss']:.4f}", block=info["block"])
        if opt.t % cfg.checkpoint_every == 0 or opt.t == opt.total_steps:
            parallel.stop_if_diverged(opt.t, state_path, hint, camera=camera)  # every rank: all stop together
        if ranks.is_main and (opt.t % cfg.checkpoint_every == 0 or opt.t == opt.total_steps):
            _save_state(state_path, camera, opt, wall_s + time.perf_counter() - t_start, history, monitor)
    bar.close()
    wall = wall_s + (time.perf_counter() - t_start if ran else 0.0)
    camera.eval()
    return {
        "steps": opt.t,
        "wall_s": wall,
        "final_loss": history[-1]["loss"] if history else math.nan,
        "cut_steps": int(sum(h.get("cut", 0) for h in history)),
        "history": history,
    }


def start_run(cfg: DesignConfig, out: "str | Path") -> tuple[Path, object, SensorFrame, OpticsSurrogate]:
    """What every design run starts from: its folder, task, sensor frame and surrogate (checked
    to render at the sensor's pitch), with the torch threads set."""
    parallel.set_threads(cfg.threads)
    return (
        Path(out),
        get_task(cfg.task),
        SensorFrame(),
        load_surrogate(cfg.surrogate, calibrated_preset("imx249").pixel_um),
    )


def claim_run_dir(out: Path, cfg: DesignConfig, ranks: parallel.Ranks, progress: bool, log):
    """Check that the batch splits over the ranks, then rank 0 checks or creates the run
    directory (config.json) while the others wait. Returns this rank's (progress, log,
    TensorBoard writer): rank 0's as given with a writer into out/tb, the others' silent
    with none."""
    from torch.utils.tensorboard import SummaryWriter

    from .config import check_run_dir

    parallel.batch_slice(cfg.batch, ranks)
    if ranks.is_main:
        check_run_dir(out, cfg)
    parallel.barrier(ranks)
    if not ranks.is_main:
        return False, (lambda m: None), None
    return progress, log, SummaryWriter(str(out / "tb"))


def run_design(cfg: DesignConfig, out: "str | Path", *, progress: bool = True, log=print) -> dict | None:
    """The whole run; returns the results (also written to out/results.json). Under torchrun
    (``torchrun --nproc_per_node N -m optix_e2e design ...``) the N processes share each
    training batch (optix_e2e.parallel); rank 0 alone evaluates and writes, and the other
    ranks return None once the trainings are done."""
    from ..scenes import ImageFolder
    from ..surrogate.refine import RefineSettings
    from ..tasks import heldout_set
    from . import evaluate as ev
    from . import outputs
    from .hybrid import OpticsMonitor, exact_gradient_steps, resolve_optics

    if cfg.task == "detection":
        from .detection_run import run_detection_design

        return run_detection_design(cfg, out, progress=progress, log=log)
    # everything the run needs is checked before the run directory is claimed
    ranks = parallel.setup("cpu")  # the design trainings run on the CPU: gloo
    out, task, frame, sur = start_run(cfg, out)
    folder = ImageFolder(cfg.images) if cfg.images else None
    mode, choice = resolve_optics(cfg)
    if ranks.distributed and mode != "surrogate":
        raise ValueError(
            f"--optics {cfg.optics} ({mode}) runs the engine inside the training steps and is not "
            f"split over processes; under torchrun use --optics surrogate"
        )
    build_camera(cfg, sur, frame=frame)
    progress, log, writer = claim_run_dir(out, cfg, ranks, progress, log)
    try:
        log(
            f"[1/4] end-to-end training: {cfg.task}, {cfg.optimizer}, {cfg.total_steps} steps, optics {mode}"
            + (f" (auto: {choice['why']})" if cfg.optics == "auto" else "")
        )
        camera = build_camera(cfg, sur, frame=frame, own_surrogate=mode == "hybrid")
        monitor = OpticsMonitor(
            camera.optics,
            mode,
            cfg.check_every,
            cfg.hybrid_threshold,
            choice["refine"],
            RefineSettings(designs=cfg.refine_designs, steps=cfg.refine_steps, seed=cfg.seed),
            writer=writer,
            name="end_to_end",
            log=log,
        )
        e2e = train(
            cfg,
            camera,
            make_optimizer(cfg, camera, cfg.optimizer),
            out,
            "end_to_end",
            progress=progress,
            writer=writer,
            frame=frame,
            folder=folder,
            log=log,
            ranks=ranks,
            monitor=monitor if ranks.is_main else None,
        )  # surrogate optics: it only measures
        nominal_values = camera.optics.base_values()
        with torch.no_grad():
            psf_ns, vig_ns = sur.psfs(nominal_values, check=False)
        # the baseline trains through the same optics model as the run: the engine's PSFs of the
        # nominal lens where the run trusts the engine, the surrogate's where it does not
        psf_nt, vig_nt = psf_ns, vig_ns
        if mode != "surrogate":
            psf_nt, vig_nt = (
                torch.as_tensor(a, dtype=torch.float32)
                for a in camera.optics.exact.psfs(nominal_values.double().numpy())
            )
        idx = camera.optics.field_index or list(range(len(sur.fields_deg)))
        fixed = FixedOptics(
            psf_nt[idx],
            vig_nt[idx],
            camera.optics.render_fields[idx],
            patch=cfg.patch,
            full_field_px=frame.full_field_px,
        )
        log(f"[2/4] nominal lens + processing fine-tuned, the same {cfg.total_steps} steps")
        nominal = build_camera(cfg, sur, fixed_optics=fixed, frame=frame)
        nom = train(
            cfg,
            nominal,
            make_optimizer(cfg, nominal, "nominal"),
            out,
            "nominal",
            progress=progress,
            writer=writer,
            frame=frame,
            folder=folder,
            log=log,
            ranks=ranks,
        )
    finally:
        if writer is not None:
            writer.close()
    if not ranks.is_main:
        return None

    t_eval = time.perf_counter()
    log("[3/4] exact PSFs of both lenses (engine) and held-out evaluation")
    final_values = camera.optics.values().detach()
    exact = exact_optics(sur, torch.stack([nominal_values, final_values]).double().numpy())
    with torch.no_grad():  # the shipped surrogate at the final design (a hybrid run's refined model: optics_model)
        psf_es, vig_es = sur.psfs(final_values, check=False)
    # field positions: each design's own chief-ray heights under exact optics, the nominal's
    # (what training used) under the surrogate's
    heights = {
        who: design_field_heights(sur, v.numpy(), exact["image_distance"][i])
        for i, (who, v) in enumerate((("nominal", nominal_values), ("end_to_end", final_values)))
    }
    h_train = camera.optics.render_fields
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
    cams = {"nominal": nominal, "end_to_end": camera}
    samples = heldout_set(
        cfg.eval_size,
        exact["psf"].shape[-1] // 2,
        cfg.eval_procedural,
        cfg.eval_level,
        frame,
        positions=POSITIONS[cfg.eval_positions],
    )
    rows: dict[str, dict[str, list]] = {}
    reused_s = 0.0  # seconds of evaluations reused from an earlier call
    for who in ("nominal", "end_to_end"):
        rows[who] = {}
        for kind in ("exact", "surrogate"):
            # an evaluation is reused only for the same camera: PSFs, vignetting, field heights and ISP
            path = out / f"eval_{who}_{kind}.json"
            psf, vig, fh = optics[who][kind]
            key = _camera_digest(psf, vig, fh, cams[who].isp, len(samples))
            cached = _read_eval_cache(path, key)
            if cached is not None:
                rows[who][kind], reused_s = cached["rows"], reused_s + float(cached.get("wall_s", 0.0))
                continue
            t0 = time.perf_counter()
            fo = FixedOptics(psf, vig, fh, patch=cfg.patch, full_field_px=frame.full_field_px)
            rows[who][kind] = ev.evaluate(
                Camera(fo, cams[who].sensor, cams[who].isp),
                tqdm(samples, desc=f"eval {who} ({kind} optics)", unit="img", disable=not progress, leave=False),
            )
            write_json_atomic(path, {"key": key, "wall_s": time.perf_counter() - t0, "rows": rows[who][kind]})

    # the room the lens has: the nominal camera's processing behind a perfect lens (the scene
    # unchanged: no blur, no vignetting; camera/stages.py PerfectOptics), the same samples and
    # noise draws
    size = int(exact["psf"].shape[-1])
    path = out / "eval_perfect_lens_exact.json"
    key = _camera_digest(
        torch.tensor([float(size)]), torch.ones(1), torch.zeros(1), nominal.isp, len(samples), tag="perfect-optics"
    )
    cached = _read_eval_cache(path, key)
    if cached is not None:
        perfect_rows, reused_s = cached["rows"], reused_s + float(cached.get("wall_s", 0.0))
    else:
        t0 = time.perf_counter()
        po = PerfectOptics(size, full_field_px=frame.full_field_px)
        perfect_rows = ev.evaluate(
            Camera(po, nominal.sensor, nominal.isp),
            tqdm(samples, desc="eval perfect lens", unit="img", disable=not progress, leave=False),
        )
        write_json_atomic(path, {"key": key, "wall_s": time.perf_counter() - t0, "rows": perfect_rows})

    log("[4/4] lens export, checks, PSF grids, panels, reports")
    fields_deg = [float(f) for f in sur.manifest["fields_deg"]]
    names = sur.param_names
    exported, checks = outputs.write_design_outputs(out, cfg, sur, nominal_values.numpy(), final_values.numpy(), exact)
    from ..scenes import bundled_photos

    # the panels: three photos at the two extremes of the field, the centre and the corner
    _panels(
        out / "panels.png",
        heldout_set(cfg.eval_size, exact["psf"].shape[-1] // 2, 0, cfg.eval_level, frame, photos=bundled_photos()[:3]),
        cams,
        optics,
    )
    from ..design.report import write_report

    for who in ("nominal", "end_to_end"):
        write_report(Lens.load(out / "lens" / f"{who}.json"), out / "report" / who)

    summary = {
        who: {**ev.summarize(rows[who]["exact"]), "surrogate": ev.summarize(rows[who]["surrogate"])}
        for who in ("nominal", "end_to_end")
    }
    results = {
        "task": cfg.task,
        "description": task.description,
        "optimizer": cfg.optimizer,
        "budget": cfg.budget,
        "seed": cfg.seed,
        "optics_eval": "exact",
        "nominal": summary["nominal"],
        "end_to_end": summary["end_to_end"],
        # the nominal camera's processing behind a perfect lens (PerfectOptics): the lens's room
        "perfect_lens": ev.summarize(perfect_rows),
        "paired": ev.paired(rows["nominal"]["exact"], rows["end_to_end"]["exact"], cfg.bootstrap, cfg.seed),
        "paired_by_zone": ev.paired_by_zone(
            rows["nominal"]["exact"], rows["end_to_end"]["exact"], cfg.bootstrap, cfg.seed
        ),
        "paired_surrogate_optics": ev.paired(
            rows["nominal"]["surrogate"], rows["end_to_end"]["surrogate"], cfg.bootstrap, cfg.seed
        ),
        "lens_zmx": str(Path(exported["zmx"]).relative_to(out)),
        "lens_json": str(Path(exported["json"]).relative_to(out)),
        "design": {
            "parameters": names,
            "nominal": [float(v) for v in nominal_values],
            "end_to_end": [float(v) for v in final_values],
            "checks": checks,
        },
        "surrogate_psf_rel_l1_per_field": {
            "fields_deg": fields_deg,
            "nominal": outputs.psf_rel_l1_per_field(psf_ns, exact["psf"][0]),
            "end_to_end": outputs.psf_rel_l1_per_field(psf_es, exact["psf"][1]),
        },
        # the exact PSFs are normalized over their window: how much of each field's flux that
        # window holds (worst channel), for both lenses
        "exact_psf_energy_in_window": {
            "fields_deg": fields_deg,
            "window_px": int(exact["psf"].shape[-1]),
            "nominal": [float(e) for e in exact["energy_in_window"][0].min(axis=-1)],
            "end_to_end": [float(e) for e in exact["energy_in_window"][1].min(axis=-1)],
        },
        "held_out": {
            "n_images": len({s.name for s in samples}),
            "n_samples": len(samples),
            "positions": cfg.eval_positions,
            "per_image": len(POSITIONS[cfg.eval_positions]),
            "size_px": cfg.eval_size,
        },
        "training": {
            k: {kk: v[kk] for kk in ("steps", "wall_s", "final_loss", "cut_steps")}
            for k, v in (("end_to_end", e2e), ("nominal", nom))
        },
        "surrogate": cfg.surrogate,
        "optics_model": {
            **monitor.summary(),
            "requested": cfg.optics,
            "choice": choice,
            "exact_gradient_steps": exact_gradient_steps(e2e["history"]),
        },
    }
    if task.isp == "hardware":
        results["isp_hyperparameters"] = {
            "nominal": nominal.isp.hyperparameters(),
            "end_to_end": camera.isp.hyperparameters(),
        }
    _write_history(out / "history.csv", {"end_to_end": e2e["history"], "nominal": nom["history"]})
    _write_rows(out / "metrics.csv", rows)
    # training (both runs, across resumes) + exact PSFs, evaluation and outputs of this call
    # + the evaluations it reused from an earlier one
    results["wall_s"] = e2e["wall_s"] + nom["wall_s"] + reused_s + (time.perf_counter() - t_eval)
    write_json_atomic(out / "results.json", results)
    return results


def _camera_digest(psf, vig, fh, isp, n_samples: int, tag: str = "") -> str:
    """A digest of what a held-out evaluation depends on besides the run's settings."""
    import hashlib

    h = hashlib.sha256(f"samples={n_samples}{tag}".encode())
    for t in (psf, vig, fh, *isp.state_dict().values()):
        h.update(torch.as_tensor(t).detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _read_eval_cache(path: Path, key: str) -> dict | None:
    """An earlier evaluation of the same camera (None: absent, stale or unreadable: evaluate again)."""
    try:
        cached = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return None
    if not (isinstance(cached, dict) and cached.get("key") == key and isinstance(cached.get("rows"), list)):
        return None
    # every row as the evaluation writes it; a hand-edited or damaged file is evaluated again
    from .evaluate import METRICS

    for r in cached["rows"]:
        if not (
            isinstance(r, dict)
            and isinstance(r.get("image"), str)
            and isinstance(r.get("position"), str)
            and all(isinstance(r.get(m), (int, float)) and not isinstance(r.get(m), bool) for m in METRICS)
            and isinstance(r.get("radius"), (int, float))
        ):
            return None
    return cached


@torch.no_grad()
def _panels(path: Path, samples, cams: dict, optics: dict, n_images: int = 3) -> None:
    """target / nominal / end-to-end for the first ``n_images`` of ``samples``, every position."""
    from .outputs import save_panels

    names = []
    for s in samples:
        if s.name not in names:
            names.append(s.name)
    rows = []
    for s in samples:
        if s.name not in names[:n_images]:
            continue
        imgs = [s.target]
        for who in ("nominal", "end_to_end"):
            psf, vig, fh = optics[who]["exact"]
            cam = cams[who]
            fo = FixedOptics(psf, vig, fh, patch=cam.optics.patch, full_field_px=cam.optics.full_field_px)
            out, _ = Camera(fo, cam.sensor, cam.isp)(
                s.scene[None], s.offset_px, torch.Generator().manual_seed(int(s.noise_seed)), final=True
            )
            imgs.append(out[0])
        rows.append((f"{s.name} ({s.position})", imgs))
    save_panels(path, rows, ["target", "nominal + fine-tuned processing", "end-to-end"])


def _write_history(path: Path, runs: dict, parts: tuple[str, ...] = LOSS_PARTS) -> None:
    import csv

    keys = history_keys(parts)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["run", *keys])
        for run, hist in runs.items():
            for h in hist:
                w.writerow([run] + [h.get(k, "") for k in keys])


def _write_rows(path: Path, rows: dict) -> None:
    import csv

    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["camera", "optics", "image", "position", "radius", "psnr_db", "ssim", "lpips", "haarpsi"])
        for who, kinds in rows.items():
            for kind, rs in kinds.items():
                for r in rs:
                    w.writerow(
                        [
                            who,
                            kind,
                            r["image"],
                            r["position"],
                            r.get("radius", ""),
                            r["psnr_db"],
                            r["ssim"],
                            r["lpips"],
                            r["haarpsi"],
                        ]
                    )
