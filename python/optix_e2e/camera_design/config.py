"""Settings of an end-to-end design run (`optix design`): budgets and the config file.

A budget fixes the schedule and the evaluation size; a TOML file (``--config``) may override
any field by name. The run directory keeps the settings it was made with (config.json) and
refuses to continue under others.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from ..device import resolve_device
from ..errors import InputError
from ..io import claim_out_dir, hold_out_dir, read_small_text, write_json_atomic
from ..tasks import get_task, plugin
from ..tasks.samples import POSITIONS, TRAIN_POSITIONS
from ..tasks.shipped_detectors import check_detector_setting, is_shipped

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib


MAX_THREADS = 1024  # torch aborts (a segmentation fault) when asked for tens of thousands
BIG = 10**7  # steps and counts: far above any real run, far below what overflows
LENS_STEPS = ("sigmoid", "range")  # DesignConfig.lens_steps
OPTICS_MODES = ("surrogate", "exact", "hybrid", "auto")  # DesignConfig.optics (hybrid.py)
REFINE_MODES = ("correction", "network")  # DesignConfig.refine (hybrid.py)

# Every numeric setting's range, checked in one place (DesignConfig.check): (low, high, low
# excluded). Floats must also be finite. A new numeric setting without a range is a test failure.
RANGES: dict[str, tuple[float, float, bool]] = {
    "seed": (0, 2**63 - 1, False),
    "crop": (16, 1024, False),
    "crop_width": (0, 1024, False),
    "batch": (1, 256, False),
    "n_cycles": (0, BIG, False),
    "steps_optics": (1, BIG, False),
    "steps_isp": (1, BIG, False),
    "n_finetune": (0, BIG, False),
    "steps_detector": (1, BIG, False),
    "lr_optics": (0.0, 10.0, True),
    "lr_isp_net": (0.0, 10.0, True),
    "lr_isp_params": (0.0, 10.0, True),
    "lr_detector": (0.0, 10.0, True),
    "lr_vanilla": (0.0, 10.0, True),
    "beta_optics": (0.0, 1e6, False),
    "beta_isp": (0.0, 1e6, False),
    "beta_detector": (0.0, 1e6, False),
    "eval_scenes": (1, 100_000, False),
    "check_every": (1, BIG, False),
    "hybrid_threshold": (0.0, 10.0, True),
    "refine_designs": (1, 100_000, False),
    "refine_steps": (1, BIG, False),
    "fields": (0, 1000, False),
    "patch": (2, 1024, False),
    "checkpoint_every": (1, BIG, False),
    "guard_band": (0.0, 100.0, True),
    "guard_weight": (0.0, 1e6, True),
    "eval_size": (16, 1024, False),
    "eval_procedural": (0, 10_000, False),
    "eval_level": (0.0, 10.0, True),
    "bootstrap": (100, 1_000_000, False),
    "threads": (0, MAX_THREADS, False),
}


def check_ranges(values: dict, ranges: dict = RANGES, what: str = "setting") -> None:
    """One error naming the first setting of ``values`` outside its range or not finite."""
    import math

    for k, (lo, hi, open_lo) in ranges.items():
        if k not in values:
            continue
        v = values[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise InputError(f"{what} {k} must be a number, got {v!r}")
        if isinstance(v, float) and not math.isfinite(v):
            raise InputError(f"{what} {k} must be a finite number, got {v}")
        if v < lo or v > hi or (open_lo and v == lo):
            raise InputError(f"{what} {k} must be {'>' if open_lo else '>='} {lo} and <= {hi}, got {v}")


@dataclass(frozen=True)
class DesignConfig:
    task: str = "iq-software"
    optimizer: str = "alg1"  # alg1 | vanilla
    budget: str = "quick"
    seed: int = 0
    surrogate: str = "paper-triplet-e2e"  # bundled name, checkpoint or run directory
    # the space the lens moves in ("": the surrogate's; else a bundled space's name or a TOML
    # file over the same parameters and base lens, e.g. paper-triplet-wide: needs optics "exact")
    space: str = ""
    optics_init: str = "nominal"  # nominal | uniform (random in the space, from the seed)
    images: str = ""  # a folder of the user's images, mixed into training (half the crops)
    # a prepared photo corpus (`optix scenes photos prepare`): its train split becomes most of the
    # training scenes (scenes/natural.py PHOTO_MIX), as in the ISP's pre-training on photographs
    photos: str = ""
    software_isp: str = ""  # the pre-trained software ISP to start from ("": the bundled one)
    # training
    crop: int = 128  # sensor pixels per side of a training crop (its height)
    # where a training batch's crop lies: "radius" (its field radius uniform: the centre and the
    # corners weigh as much as the mid-field; tasks/samples.py) or "frame" (uniform over the
    # area: trained so, the end-to-end camera lost at centre and corner; docs/e2e.md)
    train_positions: str = "radius"
    crop_width: int = 0  # its width (0: square)
    batch: int = 4
    # the schedule (docs/e2e.md, "Choosing the schedule"): one cycle, then joint fine-tuning,
    # chosen on validation batches (a training stream of another seed), not the held-out set
    n_cycles: int = 1  # Alg. 1's n_c
    steps_optics: int = 10  # n_i of the optics block
    steps_isp: int = 10  # n_i of the ISP block
    n_finetune: int = 80  # n_f
    lr_optics: float = 1e-2  # Adam, on the sigmoid-reparameterized lens parameters (paper: 1e-2)
    lr_isp_net: float = 1e-4  # the software ISP's weights (paper: 1e-4)
    lr_isp_params: float = 1e-2  # the hardware ISP's hyperparameters (their logits)
    beta_optics: float = 0.1  # Eq. 15's beta per block
    beta_isp: float = 0.0
    # the detection task's third block, the detector (tasks/detection.py)
    # the pre-trained detector to start from: a shipped detector's name (tasks/bundled/detectors.json;
    # "": "street", the first one shipped) or a checkpoint's path; the detection budgets: "street-tuned"
    detector: str = ""
    # where the hardware ISP's hyperparameters start: "random" (Alg. 1: uniform over their
    # ranges, drawn from the seed) or "detector" (the ones tuned with the start detector behind
    # the nominal camera, stored in its checkpoint by `optix detect tune`)
    isp_init: str = "random"
    steps_detector: int = 10  # n_i of the detector block
    lr_detector: float = 2e-4  # AdamW-free Adam on its weights
    beta_detector: float = 0.0
    eval_scenes: int = 100  # detection: held-out street scenes (one position each)
    lr_vanilla: float = 1e-3  # the vanilla baseline's one learning rate
    # the optics model in the loop (camera_design/hybrid.py, docs/optics-in-the-loop.md)
    # exact | surrogate | hybrid | auto (from the measured trade-off); exact, the engine with central-
    # difference gradients, for the image-quality tasks (docs/optics-in-the-loop.md: the surrogate is up
    # to 20 % off at the full field, exact costs nothing measurable on the whole run); detection too, in
    # paper-triplet-detect-wide, a space no network learned (its plugin's budgets, tasks/detection.py; its smoke budget: surrogate)
    optics: str = "exact"
    # the exact optics' lens gradient (optics/exact.py): "one-pass", the engine's vector-Jacobian
    # product (differences where a design has none, counted), or "differences", the central-
    # difference Jacobian (2P + 1 designs a step; how runs made before the one-pass gradient ran)
    exact_gradient: str = "one-pass"
    check_every: int = 10  # exact check of the current design every N steps (and after the last)
    hybrid_threshold: float = 0.02  # hybrid: refine when the worst field's PSF rel. L1 passes this
    refine: str = "correction"  # hybrid: correction (exact minus surrogate at the design) | network
    refine_designs: int = 192  # refine = network: engine designs about the design
    refine_steps: int = 150  # refine = network: fine-tune steps
    fields: int = 0  # field samples K the renderer uses in training (0: all the surrogate's)
    patch: int = 64  # overlap-add patch of the renderer
    checkpoint_every: int = 20
    # the lens's manufacturability limits at every step (camera_design/guard.py): project = the
    # step projected along the limits it leans across, then cut back; barrier = that, after a
    # log barrier on the margins within guard_band mm has steered the lens's gradient
    guard: str = "barrier"  # or "project" (docs/e2e.md, "Constraints that steer")
    guard_band: float = 0.25  # mm
    guard_weight: float = 1e-3  # the barrier's weight (loss units per log of a margin)
    # how a lens step is sized: "sigmoid" (Adam on the sigmoid's argument u: a step in the
    # parameter's units shrinks with its start's distance to a bound) or "range" (each
    # parameter's step in u scaled so that the first one is the same fraction of every range,
    # wherever its start sits: optics/differentiable.py range_step_scale; the detection task's
    # budgets, whose nominal f/4.4 sits at 0.89 of its range)
    lens_steps: str = "sigmoid"
    # evaluation
    eval_size: int = 192
    eval_procedural: int = 13  # + the bundled photos (9) = 22 held-out images, each at eval_positions
    eval_level: float = 0.7
    # frame+centre+corner: 4 stratified uniform positions per image (the headline, evaluate.py),
    # the centre and the corner, each paired apart | frame | centre-corner (tasks/samples.py)
    eval_positions: str = "frame+centre+corner"
    bootstrap: int = 2000
    threads: int = 0  # torch CPU threads (0: torch's default)
    # where the cameras run: auto (CUDA when present), cpu, cuda, cuda:K (optix_e2e.device); a run
    # may resume on another device (RESUMES_ANYWHERE), results.json says where each call ran
    device: str = "auto"
    # the networks' arithmetic (optix_e2e.precision): fp32, or bf16 / fp16 autocast for the ISP net,
    # the hardware ISP's proxy and the detector (optics, sensor, losses and metrics stay float32)
    precision: str = "fp32"

    @property
    def total_steps(self) -> int:
        blocks = plugin(self.task).blocks  # the task's blocks beside the optics and the ISP
        per_cycle = self.steps_optics + self.steps_isp + sum(getattr(self, f"steps_{b}") for b in blocks)
        return self.n_cycles * per_cycle + self.n_finetune

    @property
    def crop_hw(self) -> tuple[int, int]:
        return self.crop, self.crop_width or self.crop

    def check(self) -> "DesignConfig":
        check_ranges(dataclasses.asdict(self))
        get_task(self.task)
        if self.optimizer not in ("alg1", "vanilla"):
            raise InputError(f"optimizer must be alg1 or vanilla, got {self.optimizer!r}")
        if self.eval_positions not in POSITIONS:
            raise InputError(f"eval_positions must be one of {', '.join(POSITIONS)}, got {self.eval_positions!r}")
        if self.optics not in OPTICS_MODES:
            raise InputError(f"optics must be one of {', '.join(OPTICS_MODES)}, got {self.optics!r}")
        from ..optics.exact import EXACT_GRADIENTS

        if self.exact_gradient not in EXACT_GRADIENTS:
            raise InputError(f"exact_gradient must be one of {', '.join(EXACT_GRADIENTS)}, got {self.exact_gradient!r}")
        if self.refine not in REFINE_MODES:
            raise InputError(f"refine must be one of {', '.join(REFINE_MODES)}, got {self.refine!r}")
        from .guard import GUARD_MODES

        if self.guard not in GUARD_MODES:
            raise InputError(f"guard must be one of {', '.join(GUARD_MODES)}, got {self.guard!r}")
        if self.lens_steps not in LENS_STEPS:
            raise InputError(f"lens_steps must be one of {', '.join(LENS_STEPS)}, got {self.lens_steps!r}")
        if not self.hybrid_threshold > 0:
            raise InputError(f"hybrid_threshold must be > 0, got {self.hybrid_threshold}")
        if self.fields < 0 or self.fields == 1:
            raise InputError(f"fields must be 0 (all) or at least 2, got {self.fields}")
        if self.space and self.optics != "exact":
            raise InputError(
                f"space {self.space!r} is not the surrogate's: the lens moves where the network was not "
                f'trained, so its optics must be the engine\'s (optics = "exact"), got optics = {self.optics!r}'
            )
        if self.train_positions not in TRAIN_POSITIONS:
            raise InputError(
                f"train_positions must be one of {', '.join(TRAIN_POSITIONS)}, got {self.train_positions!r}"
            )
        if self.isp_init not in ("random", "detector"):
            raise InputError(f"isp_init must be random or detector, got {self.isp_init!r}")
        if self.isp_init == "detector" and ("detector" not in plugin(self.task).blocks or not self.detector):
            raise InputError(
                "isp_init = detector starts the hardware ISP where `optix detect tune` left it: it needs "
                "the detection task and a tuned checkpoint as its detector setting (street-tuned, or one "
                "`optix detect tune` made); or set isp_init = random"
            )
        if self.optics_init not in ("nominal", "uniform"):
            raise InputError(f"optics_init must be nominal or uniform, got {self.optics_init!r}")
        for k in (
            "crop",
            "batch",
            "steps_optics",
            "steps_isp",
            "steps_detector",
            "eval_size",
            "eval_scenes",
            "patch",
            "checkpoint_every",
            "check_every",
            "refine_designs",
            "refine_steps",
        ):
            if getattr(self, k) < 1:
                raise InputError(f"{k} must be >= 1, got {getattr(self, k)}")
        if self.crop_width < 0 or self.crop_width % 16:
            raise InputError(f"crop_width must be 0 (square) or a positive multiple of 16, got {self.crop_width}")
        for k in ("crop", "eval_size", "patch"):
            if getattr(self, k) % 16 if k != "patch" else getattr(self, k) % 2:
                raise InputError(f"{k} must be a multiple of {16 if k != 'patch' else 2}, got {getattr(self, k)}")
        for k in ("lr_optics", "lr_isp_net", "lr_isp_params", "lr_detector", "lr_vanilla", "eval_level"):
            if not getattr(self, k) > 0:
                raise InputError(f"{k} must be > 0, got {getattr(self, k)}")
        if self.n_cycles < 0 or self.n_finetune < 0 or self.eval_procedural < 0 or self.bootstrap < 100:
            raise InputError("n_cycles, n_finetune, eval_procedural must be >= 0 and bootstrap >= 100")
        for k in ("beta_optics", "beta_isp", "beta_detector", "seed", "threads"):
            if getattr(self, k) < 0:
                raise InputError(f"{k} must be >= 0, got {getattr(self, k)}")
        for k in ("crop", "crop_width", "eval_size"):
            if getattr(self, k) > 1024:
                raise InputError(
                    f"{k} must be at most 1024 pixels (the sensor frame is 1920 x 1200), got {getattr(self, k)}"
                )
        if self.images and not Path(self.images).is_dir():
            raise InputError(f"images: no such folder {self.images}")
        if self.photos and not Path(self.photos).is_dir():
            raise InputError(f"photos: no such folder {self.photos}")
        if self.software_isp and not Path(self.software_isp).is_file():
            raise InputError(f"software_isp: no such file {self.software_isp}")
        if self.detector:
            check_detector_setting(self.detector)
        if self.total_steps < 1:
            raise InputError("the schedule has no step (n_cycles and n_finetune both 0)")
        from ..precision import resolve_precision

        resolve_precision(self.precision, resolve_device(self.device, option="device"), option="precision")
        return self

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


# smoke: seconds, for tests; quick: the main job (./run.sh); full: the figures we report.
BUDGETS: dict[str, dict] = {
    "smoke": dict(
        crop=32,
        batch=1,
        n_cycles=1,
        steps_optics=2,
        steps_isp=2,
        n_finetune=2,
        eval_size=32,
        check_every=3,
        eval_procedural=1,
        checkpoint_every=2,
        bootstrap=200,
    ),
    "quick": dict(),
    "full": dict(n_cycles=2, steps_optics=25, steps_isp=25, n_finetune=300, eval_size=256),
}


def task_default(task: str, budget: str, key: str):
    """The value setting ``key`` takes for ``task`` at ``budget`` when neither a config file
    nor the command line sets it."""
    values = {**BUDGETS.get(budget, {}), **plugin(task).budgets.get(budget, {})}
    return values.get(key, getattr(DesignConfig, key))


PATH_SETTINGS = ("images", "photos", "software_isp", "detector")  # settings that name files or folders


def read_config_file(path: Path) -> dict:
    """A design config file's settings as written, its relative paths (``PATH_SETTINGS``) made
    absolute against the file's folder; one error naming the file if it cannot be read."""
    try:
        data = tomllib.loads(read_small_text(path, what="config file"))
    except FileNotFoundError:
        raise InputError(f"config file not found: {path}") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read the config file ({err.strerror})") from None
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"{path}: not valid TOML: {err}") from None
    except RecursionError:
        raise InputError(f"{path}: not a config file (nested too deeply to parse)") from None
    for k in PATH_SETTINGS:
        v = data.get(k)
        if isinstance(v, str) and v and not Path(v).is_absolute() and not (k == "detector" and is_shipped(v)):
            data[k] = str((path.parent / v).resolve())  # relative to the config file
    return data


#: settings an optimizer never reads: given under it, they are refused (Alg. 1's per-block rates and
#: prox weights under vanilla's one rate, and vanilla's rate under Alg. 1; build.make_optimizer)
UNUSED_BY: dict[str, tuple[str, ...]] = {
    "vanilla": ("lr_optics", "lr_isp_net", "lr_isp_params", "lr_detector", "beta_optics", "beta_isp", "beta_detector"),
    "alg1": ("lr_vanilla",),
}


def load_config(
    budget: "str | None" = "quick", file: "str | Path | None" = None, **overrides
) -> tuple[DesignConfig, frozenset[str]]:
    """The budget's settings (None: quick, not given), then the TOML file's, then ``overrides``
    (None values ignored); with the names of the settings the user gave (the budget unless None,
    the file's, the non-None overrides'): a resumed run takes every other setting from its
    folder (``resume_settings``)."""
    budget_given = budget is not None
    budget = "quick" if budget is None else budget
    if budget not in BUDGETS:
        raise InputError(f"unknown budget {budget!r}: known budgets are {', '.join(BUDGETS)}")
    fields = {f.name for f in dataclasses.fields(DesignConfig)}
    values = {"budget": budget, **BUDGETS[budget]}
    data = read_config_file(Path(file)) if file is not None else {}
    task = overrides.get("task") or data.get("task")
    values.update(plugin(task or DesignConfig.task).budgets.get(budget, {}))
    given = {k for k, v in overrides.items() if v is not None}
    where = "on the command line"
    if file is not None:
        path = Path(file)
        where = f"in {path}"
        unknown = sorted(set(data) - fields)
        if "budget" in data:
            raise InputError(f"{path}: the budget is chosen with --budget, not in the config file")
        if unknown:
            raise InputError(f"{path}: unknown setting(s) {', '.join(unknown)} (known: {', '.join(sorted(fields))})")
        for k, v in data.items():
            want = type(getattr(DesignConfig, k))
            if want is float and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if not isinstance(v, want) or isinstance(v, bool) != (want is bool):
                raise InputError(f"{path}: {k} must be a {want.__name__}, got {v!r}")
            values[k] = v
            if overrides.get(k) is not None and overrides[k] != v:  # the command line and the file disagree
                raise InputError(f"{path}: {k} = {v!r} here, {overrides[k]!r} on the command line; say it once")
        given |= set(data)
        check_ranges(data, what=f"{path}: setting")
        # a GPU the machine lacks, a precision it cannot run: the error names the file
        if "device" in data:
            resolve_device(data["device"], option=f"{path}: device")
        if "precision" in data:
            from ..precision import resolve_precision

            where_run = overrides.get("device") or data.get("device") or DesignConfig.device
            resolve_precision(data["precision"], resolve_device(where_run), option=f"{path}: precision")
    values.update({k: v for k, v in overrides.items() if v is not None})
    optimizer = values.get("optimizer", DesignConfig.optimizer)
    unused = sorted(given & set(UNUSED_BY.get(optimizer, ())))
    if unused:
        raise InputError(
            f"{', '.join(unused)} given {where}, but the {optimizer} optimizer does not use "
            f"{'it' if len(unused) == 1 else 'them'}; remove {'it' if len(unused) == 1 else 'them'}"
            + (" (vanilla's one rate is lr_vanilla)" if optimizer == "vanilla" else "")
        )
    return DesignConfig(**values).check(), frozenset(given | ({"budget"} if budget_given else set()))


def make_config(budget: "str | None" = "quick", file: "str | Path | None" = None, **overrides) -> DesignConfig:
    """``load_config``'s settings alone."""
    return load_config(budget, file, **overrides)[0]


#: settings a run directory does not hold its run to: a run made on one device resumes on another
RESUMES_ANYWHERE = ("device",)


def read_run_config(out: "str | Path") -> "dict | None":
    """The settings a run folder was made with (its config.json), None where it has none yet;
    one error if the file is damaged or does not name every setting of today's DesignConfig
    (a folder made before a setting existed: config.json gains it, with the value the run used)."""
    path = Path(out) / "config.json"
    if not path.is_file():
        return None
    try:
        old = json.loads(read_small_text(path, what="run config"))
    except (OSError, ValueError, RecursionError):  # unreadable, not UTF-8, not JSON, too deep
        old = None
    if not isinstance(old, dict):
        raise InputError(f"{path} is damaged; remove the directory or choose another --out")
    missing = [f.name for f in dataclasses.fields(DesignConfig) if f.name not in old]
    if missing:
        one = len(missing) == 1
        raise InputError(
            f"{path} does not say how the run was made for {', '.join(missing)} (made before "
            f"{'that setting' if one else 'those settings'} existed): add {'it' if one else 'them'} to "
            f"config.json with the value{'' if one else 's'} the run used, or use another --out"
        )
    return old


def run_config(out: "str | Path") -> DesignConfig:
    """The settings a finished or interrupted run folder was made with; one error if it has none."""
    old = read_run_config(out)
    if old is None:
        raise InputError(f"{out}: not a design run folder (no config.json)")
    unknown = sorted(set(old) - {f.name for f in dataclasses.fields(DesignConfig)})
    if unknown:
        raise InputError(f"{Path(out) / 'config.json'}: settings this version does not have: {', '.join(unknown)}")
    return DesignConfig(**old)


def resume_settings(out: "str | Path", cfg: DesignConfig, given: "frozenset[str] | None") -> DesignConfig:
    """The settings a run in ``out`` goes on with: where the folder holds a run (config.json),
    every setting the user did not give (``given``, from load_config; None: all given) is the
    folder's, so a run resumes as it was made whatever today's defaults are; check_run_dir then
    holds the given ones to the folder's. ``cfg`` for a new folder. Read-only: every rank may
    call it."""
    old = read_run_config(out)
    if old is None or given is None:
        return cfg
    taken = {
        f.name: old[f.name]
        for f in dataclasses.fields(DesignConfig)
        if f.name not in given and f.name not in RESUMES_ANYWHERE and old[f.name] != getattr(cfg, f.name)
    }
    return dataclasses.replace(cfg, **taken).check() if taken else cfg


def check_run_dir(out: Path, cfg: DesignConfig) -> None:
    """Write config.json (and inputs.json, what its file settings hold) in a new run directory;
    in an existing one, refuse other settings."""
    from .inputs import content_changed, same_content
    from .inputs import record as record_inputs

    hold_out_dir(out, "design run")  # one command at a time writes into a run folder
    old = read_run_config(out)
    if old is not None:
        new = cfg.to_json()
        diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k) and k not in RESUMES_ANYWHERE)
        # a file setting at another path that holds the same content (the run folder and its
        # inputs copied to another machine): the same run (camera_design/inputs.py)
        diff = [k for k in diff if not (k in PATH_SETTINGS and same_content(out, k, old.get(k), new.get(k)))]
        if diff:
            detail = ", ".join(f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in diff)
            raise InputError(f"{out} was made with other settings ({detail}); use another --out or the same settings")
        changed = [k for k in PATH_SETTINGS if new.get(k) and content_changed(out, k, new[k])]
        if changed:
            detail = ", ".join(f"{k} ({new[k]})" for k in changed)
            raise InputError(
                f"{out}: what {detail} holds changed since the run was made (inputs.json); "
                "restore it, or use another --out"
            )
        if not (out / "inputs.json").exists():  # a run made before inputs.json: recorded now, as resumed
            record_inputs(out, new, PATH_SETTINGS)
        return
    claim_out_dir(out, "design run", marker="config.json")
    out.mkdir(parents=True, exist_ok=True)
    settings = cfg.to_json()
    write_json_atomic(out / "config.json", settings)
    record_inputs(out, settings, PATH_SETTINGS)
