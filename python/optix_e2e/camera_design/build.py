"""What a design run is built from: the surrogate (checked to render at the sensor's pitch), the
starting values of the lens and the ISP (Alg. 1's initialization), the camera, and Alg. 1 or
vanilla over its parameter blocks. The same builder serves the end-to-end camera and the
nominal baseline (its optics fixed)."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import torch

from .. import parallel
from ..camera import (
    Camera,
    FixedOptics,
    HardwareISPStage,
    SensorStage,
    SoftwareISPStage,
    calibrated_preset,
)
from ..camera.stages import image_height_fractions
from ..dataset.manifest import space_and_base
from ..errors import InputError
from ..isp import params as hp
from ..isp.proxy import ISPProxy
from ..isp.software import SoftwareISP
from ..lens_design.space import load_space
from ..optics import DifferentiableOptics
from ..precision import apply_precision, grad_scaler, resolve_precision
from ..surrogate.checkpoint import OpticsSurrogate
from ..surrogate.ground_truth import exact_optics
from ..tasks import SensorFrame, get_task
from ..tasks.detector_train import load_detector
from ..tasks.shipped_detectors import detector_file
from .alg1 import Block, ProximalCompositional, Vanilla
from .config import DesignConfig
from .guard import Manufacturable
from .outputs import design_lens

SOFTWARE_ISP = Path(__file__).resolve().parent.parent / "isp" / "bundled" / "software_isp.pt"


def load_surrogate(spec: str, pixel_um: float | None = None) -> OpticsSurrogate:
    """The optics surrogate, checked to render at the sensor's pitch (``pixel_um``)."""
    sur = OpticsSurrogate.load(spec)
    if pixel_um is not None:
        pitch = float(sur.manifest.get("settings", {}).get("sensor_pixel_um", float("nan"))) * sur.bin
        if sur.psf_kind != "psf_sensor" or not math.isclose(pitch, pixel_um, rel_tol=1e-6):
            raise InputError(
                f"surrogate {spec}: its PSFs are {sur.psf_kind} at {pitch} um per pixel; the camera "
                f"renders at the sensor's {pixel_um} um (train it on psf_sensor, --bin 1)"
            )
    return sur


def base_lens_f_number(sur: OpticsSurrogate) -> float:
    _, base = space_and_base(sur.manifest)
    return float(base.paraxial()["f_number"])


_STARTS: dict = {}  # (surrogate, space, optics, seed) -> (values, record): the draw is made once per process


def initial_optics_values(cfg: DesignConfig, optics: DifferentiableOptics) -> torch.Tensor:
    """The nominal design, or a uniform draw inside the space's ranges (seeded), redrawn until
    it is manufacturable (as the dataset's designs are) and, where the run's optics are the
    engine's (exact or hybrid optics, or a space the surrogate was not trained on: ``space``),
    until the engine can render it (optics.exact.unrenderable:
    its PSFs inside the window, on the engine's FFT). ``start_record`` says how many draws it took."""
    if cfg.optics_init == "nominal":
        return optics.base_values()
    key = (cfg.surrogate, cfg.space, cfg.optics, int(cfg.seed))
    if key in _STARTS:
        return _STARTS[key][0].clone()
    from ..optics.exact import unrenderable

    rng = np.random.default_rng([3, int(cfg.seed)])  # stream tag 3: optics init (1: batches, 2: ISP init)
    man = optics.surrogate.manifest
    guard = Manufacturable(man) if man else None
    counts = {"draws": 0, "not_manufacturable": 0, "not_renderable": 0}
    last = ""
    for _ in range(MAX_START_DRAWS):
        counts["draws"] += 1
        u = torch.as_tensor(rng.random(len(optics.lo)), dtype=torch.float32)
        v = optics.lo + (optics.hi - optics.lo) * (0.02 + 0.96 * u)
        if guard is not None and guard.problems(v.numpy()):
            counts["not_manufacturable"] += 1
            continue
        if engine_start(cfg) and (last := unrenderable(man, v.double().numpy())):
            counts["not_renderable"] += 1
            continue
        _STARTS[key] = (v, counts)
        return v.clone()
    raise InputError(
        f"no uniform start in {MAX_START_DRAWS} draws of the space that is manufacturable"
        + (f" and renderable (the last refused: {last})" if engine_start(cfg) else "")
        + f"; seed {cfg.seed}: {counts}"
    )


MAX_START_DRAWS = 20000


def engine_start(cfg: DesignConfig) -> bool:
    """Whether the run's lens steps go through the engine (a random start must then be one the
    engine renders): exact or hybrid optics, or a space other than the surrogate's."""
    return bool(cfg.space) or cfg.optics in ("exact", "hybrid")


def start_record(cfg: DesignConfig) -> dict:
    """How the lens's start was drawn (results.json): the nominal, or the uniform draw's counts."""
    if cfg.optics_init == "nominal":
        return {"init": "nominal"}
    rec = _STARTS.get((cfg.surrogate, cfg.space, cfg.optics, int(cfg.seed)))
    return {
        "init": "uniform",
        "seed": cfg.seed,
        "condition": "manufacturable"
        + (" and renderable by the engine (the run's lens steps go through it)" if engine_start(cfg) else ""),
        **(rec[1] if rec else {}),
        **({"values": [float(x) for x in rec[0]]} if rec else {}),
    }


def design_field_heights(sur: OpticsSurrogate, values, image_distance: float) -> torch.Tensor:
    """The surrogate's fields placed where the design ``values`` images them, its image plane
    at ``image_distance`` (the chief rays' heights as fractions of the full field)."""
    return image_height_fractions(design_lens(sur.manifest, values, image_distance), sur.fields_deg)


def nominal_field_heights(sur: OpticsSurrogate) -> torch.Tensor:
    """The surrogate's fields placed where the nominal lens images them (refocused as its
    dataset was): the renderer's field positions in training."""
    if not sur.manifest:
        return sur.fields
    space, base = space_and_base(sur.manifest)
    return design_field_heights(sur, space.values(base.data), float(base.data["surfaces"][-1]["thickness"]))


def nominal_shading(sur: OpticsSurrogate, nominal_values, fallback: str | None = None):
    """The nominal lens's exact relative illumination [K, C] (the engine's, as the run's
    evaluation computes it: surrogate.ground_truth.exact_optics), the heights [K] where its chief
    rays land (fractions of the full field) and the exact PSFs' window (pixels)."""
    values = np.asarray(torch.as_tensor(nominal_values).detach().cpu().double().numpy(), np.float64)
    exact = exact_optics(sur, values[None], fallback=fallback)
    vignetting = torch.as_tensor(exact["vignetting"][0], dtype=torch.float32)
    heights = design_field_heights(sur, values, float(exact["image_distance"][0]))
    return vignetting, heights, int(exact["psf"].shape[-1])


def delta_lens(
    sur: OpticsSurrogate,
    nominal_values,
    *,
    patch: int,
    full_field_px: float,
    fallback: str | None = None,
) -> FixedOptics:
    """The ideal lens of a design run (results.json ``ideal_lens``; benches/lens_room.py
    ``--lens delta``): a one-pixel PSF at every field and the nominal's relative illumination,
    through the renderer (FixedOptics) at the nominal's chief-ray heights, in the exact PSFs'
    window: what the simulator makes of a lens that blurs nothing and shades as the nominal
    does. The one definition of it."""
    vignetting, heights, window = nominal_shading(sur, nominal_values, fallback)
    delta = torch.zeros(len(heights), vignetting.shape[1], window, window)
    delta[..., window // 2, window // 2] = 1.0
    return FixedOptics(delta, vignetting, heights, patch=patch, full_field_px=full_field_px)


#: the hardware ISP's start for the untuned baseline: its default hyperparameters (isp.params,
#: the out-of-the-box tuning), held this close to a bound where a default sits on one (the
#: stage's sigmoid never reaches it)
UNTUNED_EPS = 1e-6


def tuned_isp_unit(path: "str | Path") -> torch.Tensor:
    """The hardware ISP's hyperparameters (range-normalized, in (0, 1)) tuned with the detector
    checkpoint at ``path``; one error naming the file if it holds none."""
    _, ck = load_detector(path)
    u = ck.get("isp_unit")
    n = len(hp.NAMES)
    if not (isinstance(u, list) and len(u) == n and all(isinstance(v, float) and 0.0 < v < 1.0 for v in u)):
        raise InputError(
            f"{path}: no tuned ISP hyperparameters ({n} values in (0, 1)) in this detector checkpoint: "
            f"make it with `optix detect tune`, or set isp_init = random"
        )
    return torch.tensor(u, dtype=torch.float32)


def initial_isp_unit(cfg: DesignConfig) -> torch.Tensor:
    """Alg. 1's initialization of P_ISP: uniform random over the ranges (seeded); with
    ``isp_init = "detector"``, the hyperparameters tuned with the start detector."""
    if cfg.isp_init == "detector":
        return tuned_isp_unit(detector_file(cfg.detector))
    rng = np.random.default_rng([2, int(cfg.seed)])
    return torch.as_tensor(hp.to_unit(hp.sample(rng)), dtype=torch.float32)


def build_camera(
    cfg: DesignConfig,
    sur: OpticsSurrogate,
    *,
    fixed_optics: FixedOptics | None = None,
    frame: SensorFrame = SensorFrame(),
    own_surrogate: bool = False,
    device: "torch.device | str" = "cpu",
    untuned: bool = False,
) -> Camera:
    """The camera at its initialization: the same for Alg. 1, vanilla and the nominal baseline
    (apart from the optics, fixed at the nominal for the latter). ``own_surrogate``: the optics
    get a copy of the surrogate (a hybrid run refines its own). ``untuned``: the processing as
    it is before any fine-tuning, for the untuned baseline (results.json ``nominal_untuned``):
    the pre-trained software ISP (as always), the hardware ISP at its default hyperparameters
    instead of the run's seeded draw. Built on the CPU (the seeded starts are drawn there), then
    moved to ``device`` whole."""
    task = get_task(cfg.task)
    if fixed_optics is None:
        optics = DifferentiableOptics(
            copy.deepcopy(sur) if own_surrogate else sur, patch=cfg.patch, full_field_px=frame.full_field_px
        )
        optics.exact_gradient = cfg.exact_gradient
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
        if untuned:
            unit, eps = torch.as_tensor(hp.to_unit(hp.defaults()), dtype=torch.float32), UNTUNED_EPS
        else:
            unit, eps = initial_isp_unit(cfg), 1e-3
        isp = HardwareISPStage(ISPProxy.load(), unit, preset.cfa, preset.adc_bits, eps=eps)
    camera = Camera(optics, sensor, isp).to(device)
    apply_precision(camera, resolve_precision(cfg.precision, device, option="precision"))  # the ISP's network
    return camera


BLOCK_SETTINGS = {
    "optics": ("lr_optics", "steps_optics", "beta_optics"),
    "isp": (None, "steps_isp", "beta_isp"),
    "detector": ("lr_detector", "steps_detector", "beta_detector"),
}


def lens_step_scale(cfg: DesignConfig, camera, start) -> torch.Tensor | None:
    """The per-parameter factors on the lens's steps (``cfg.lens_steps = "range"``:
    DifferentiableOptics.range_step_scale at the run's ``start`` values), None for Adam's own
    steps in u ("sigmoid") or a camera without a lens to move."""
    if cfg.lens_steps != "range" or not isinstance(camera.optics, DifferentiableOptics):
        return None
    return camera.optics.range_step_scale(start)


def make_optimizer(cfg: DesignConfig, camera, kind: str):
    """Alg. 1 ("alg1") or vanilla ("vanilla") over the camera's blocks (optics, ISP, and the
    detection task's detector). The nominal baseline ("nominal": the lens fixed) gets exactly
    as many updates per processing block as the end-to-end run of ``cfg.optimizer`` gives that
    block (issue 34): under Alg. 1 the same schedule without the optics block (each processing
    block's own n_i, learning rate and beta, the same n_c and n_f: n_c n_i + n_f updates);
    under vanilla the vanilla optimizer over the processing blocks for ``cfg.total_steps``
    steps (every block at every step)."""
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
        kind = cfg.optimizer
        blocks = [b for b in blocks if b.name != "optics"]  # (a fixed lens has no block anyway)
    if kind == "vanilla":
        opt = Vanilla(blocks, cfg.lr_vanilla, cfg.total_steps)
    else:
        opt = ProximalCompositional(blocks, cfg.n_cycles, cfg.n_finetune)
    dev = camera.device
    opt.scaler = grad_scaler(dev, resolve_precision(cfg.precision, dev, option="precision"))  # fp16 only
    return opt


def start_run(cfg: DesignConfig, out: "str | Path") -> tuple[Path, object, SensorFrame, OpticsSurrogate]:
    """What every design run starts from: its folder, task, sensor frame and surrogate (checked
    to render at the sensor's pitch), with the torch threads set."""
    parallel.set_threads(cfg.threads)
    sur = load_surrogate(cfg.surrogate, calibrated_preset("imx249").pixel_um)
    if cfg.space:
        space, base = load_space(cfg.space)
        # a space over other parameters of the same lens: the surrogate gives only the terms
        # (the run's optics are exact whenever a space is set: DesignConfig.check)
        sur = sur.in_space(space, base, source=cfg.space, network=space.names == sur.param_names)
    return Path(out), get_task(cfg.task), SensorFrame(), sur
