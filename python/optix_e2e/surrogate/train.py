"""Training of the optics surrogate (paper Eq. 7-8) with TensorBoard logs, a tqdm bar, a
held-out validation split, and checkpoints that a later run of the same command resumes.

``out_dir`` holds:
  surrogate.pt   the model (an ``OpticsSurrogate`` checkpoint), rewritten at every validation
  state.pt       model + optimizer + step + random state + history: what resuming needs
  tb/            TensorBoard logs (train/loss and its four terms, val/*, lr)
  train.json     summary: config, data, steps, time, validation history

Under ``torchrun --nproc_per_node N`` the N processes train one model with
DistributedDataParallel (optix_e2e.parallel): every rank draws the same global batch of
(design, field) samples from the seed and computes the samples of the training designs it
holds (design positions rank, rank + N, ...: each design in one rank's memory, none twice),
so the run follows the single-process run's path; rank 0 validates and writes everything.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace
from dataclasses import fields as dc_fields
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .. import parallel
from ..device import resolve_device
from ..errors import InputError
from ..io import claim_out_dir, save_atomic, tensorboard_writer, write_record_atomic
from ..torchfile import DAMAGED_STATE_ERRORS, load_plain
from .checkpoint import OpticsSurrogate
from .data import design_indices, load_arrays, psf_grid, psf_pitch_um, to_tensors
from .loss import LossWeights, optics_loss_terms
from .model import SurrogateConfig

# changing these makes a different model or different data: resuming refuses
MAX_STEPS = 10_000_000  # the command line's maximum of --steps
_FIXED = (
    "psf",
    "bin",
    "hidden",
    "depth",
    "base_channels",
    "n_up",
    "val_designs",
    "max_designs",
    "seed",
    "batch",
    "loss_pixel",
    "loss_fourier",
    "loss_gradient",
    "loss_vignetting",
    "init",
)


@dataclass
class TrainConfig:
    psf: str = "psf_sensor"  # "psf_sensor" (sensor pitch) or "psf" (super-resolved)
    bin: int = 1  # sum bin x bin blocks of the PSFs first
    hidden: int = 256
    depth: int = 4
    base_channels: int = 64
    n_up: int = 2
    steps: int = 20000
    batch: int = 256  # (design, field) samples per step
    lr: float = 2e-3
    warmup: int = 200
    clip_grad: float = 1.0
    val_designs: int = 256  # designs held out of training (chosen with the seed)
    max_designs: int = 0  # use only the first N designs (0: all)
    val_every: int = 500
    minutes: float = 0.0  # stop after this much training time in all (0: run all steps)
    seed: int = 0
    threads: int = 0  # torch CPU threads (0: torch's default)
    device: str = "auto"  # auto: CUDA when present
    loss_pixel: float = 1.0
    loss_fourier: float = 1.0
    loss_gradient: float = 1.0
    loss_vignetting: float = 1.0
    init: str = ""  # start from this surrogate's weights (a fine-tune; same architecture)

    @property
    def weights(self) -> LossWeights:
        return LossWeights(self.loss_pixel, self.loss_fourier, self.loss_gradient, self.loss_vignetting)


def _lr(cfg: TrainConfig, step: int, seconds: float) -> float:
    """Linear warm-up, then cosine decay to 1% over the steps or the time budget, whichever
    runs out first (so a time-boxed CPU run still anneals)."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    frac = step / max(cfg.steps, 1)
    if cfg.minutes:
        frac = max(frac, seconds / (60 * cfg.minutes))
    return cfg.lr * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * min(frac, 1.0))))


@torch.no_grad()
def predict_all(model: OpticsSurrogate, params: torch.Tensor, batch_designs: int = 256):
    """PSFs and vignetting of every trained field for raw params [N, P] (no range check:
    the caller's data)."""
    psf, vig = [], []
    for i in range(0, params.shape[0], batch_designs):
        p, v = model.psfs(params[i : i + batch_designs], check=False)
        psf.append(p)
        vig.append(v)
    return torch.cat(psf), torch.cat(vig)


@torch.no_grad()
def validate(model: OpticsSurrogate, t: dict) -> dict:
    model.eval()
    psf, vig = predict_all(model, t["params"])
    model.train()
    rel = (psf - t["psf"]).abs().sum((-2, -1))  # [N, K, C]: relative L1 of unit-sum PSFs
    verr = (vig - t["vignetting"]).abs()
    return {
        "psf_rel_l1_median": float(rel.median()),
        "psf_rel_l1_mean": float(rel.mean()),
        "vignetting_abs_err_median": float(verr.median()),
        "vignetting_abs_err_max": float(verr.max()),
    }


def _split(designs: np.ndarray, n_val: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    if not 0 <= n_val < len(designs):
        raise InputError(f"val_designs {n_val} must leave training designs out of {len(designs)}")
    perm = np.random.default_rng(seed).permutation(len(designs))
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def rank_designs(
    designs: np.ndarray, val_designs: int, seed: int, rank: int = 0, world: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(training designs, validation designs, this rank's training designs): the seeded split
    of the dataset's ``designs``, and the training designs at positions rank, rank + world,
    ... (ascending: the global batch's position p is rank p % world's row p // world)."""
    tr, va = _split(designs, val_designs, seed)
    if len(tr) < world:
        raise InputError(f"{len(tr)} training designs cannot be shared by {world} processes")
    return designs[tr], designs[va], designs[tr][rank::world]


def build_model(cfg: TrainConfig, man: dict, train_vig: np.ndarray, meta: dict) -> OpticsSurrogate:
    params = man["space"]["parameters"]
    mc = SurrogateConfig(
        n_params=len(params),
        channels=len(man["channels"]),
        psf_size=psf_grid(man, cfg.psf, cfg.bin),
        hidden=cfg.hidden,
        depth=cfg.depth,
        base_channels=cfg.base_channels,
        n_up=cfg.n_up,
    )
    model = OpticsSurrogate(
        mc,
        param_names=[p["name"] for p in params],
        param_mean=man["param_mean"],
        param_std=man["param_std"],
        param_min=[p["min"] for p in params],
        param_max=[p["max"] for p in params],
        fields_deg=man["fields_deg"],
        pitch_um=psf_pitch_um(man, cfg.psf, cfg.bin),
        psf_kind=cfg.psf,
        bin=cfg.bin,
        channel_names=man["channel_names"],
        manifest=man,
        meta=meta,
    )
    with torch.no_grad():  # start the vignetting head at the data's mean per channel
        model.net.vignetting_head.weight.mul_(0.1)
        model.net.vignetting_head.bias.copy_(torch.as_tensor(train_vig.reshape(-1, train_vig.shape[-1]).mean(0)))
    return model


def _start_from(model: OpticsSurrogate, spec: str) -> None:
    """Copy the network weights of the surrogate ``spec`` (a checkpoint, a run directory or a
    bundled name) into ``model``: a fine-tune on new data. Its architecture (but the input
    width), fields and PSF grid must be the model's, and its parameters the first of the
    model's: a space widened by parameters appended at the end (the detection space adds the
    f-number to the e2e space) starts from a network that ignores them (zero input weights).
    The first layer is re-expressed for the model's input normalization, so the started
    model gives the source's outputs exactly where the new parameters sit at their mean."""
    src = OpticsSurrogate.load(spec)
    n_src = src.cfg.n_params
    same = (
        replace(src.cfg, n_params=model.cfg.n_params) == model.cfg
        and list(model.param_names[:n_src]) == list(src.param_names)
        and torch.equal(src.fields.cpu(), model.fields.cpu())
        and src.pitch_um == model.pitch_um
    )
    if not same:
        raise InputError(
            f"--init {spec}: its architecture, parameters, fields or PSF pitch differ from this run's "
            f"(its parameters must be the first of this space's)"
        )
    state = {k: v.float() for k, v in src.net.state_dict().items()}
    w, b = state["encoder.0.weight"].double(), state["encoder.0.bias"].double()  # [H, P_src + 1], [H]
    # w x_src + b with x_src = (v - m_src) / s_src and v = m + s x: weights w s / s_src on x,
    # the bias taking w (m - m_src) / s_src
    m_src, s_src = src.param_mean.double().cpu(), src.param_std.double().cpu()
    m, s = model.param_mean.double().cpu()[:n_src], model.param_std.double().cpu()[:n_src]
    w_par = w[:, :n_src] * (s / s_src)
    b = b + w[:, :n_src] @ ((m - m_src) / s_src)
    extra = torch.zeros(w.shape[0], model.cfg.n_params - n_src, dtype=w.dtype)
    state["encoder.0.weight"] = torch.cat([w_par, extra, w[:, n_src:]], dim=1).float()
    state["encoder.0.bias"] = b.float()
    model.net.load_state_dict(state)


def _vignetting_mean(vig: torch.Tensor, ranks: parallel.Ranks) -> np.ndarray:
    """The mean relative illumination per channel over every rank's training designs and
    fields, as a [1, C] array (what build_model averages)."""
    v = vig.double().reshape(-1, vig.shape[-1])
    tot = parallel.all_sum(torch.cat([v.sum(0), torch.tensor([float(v.shape[0])], dtype=torch.float64)]), ranks)
    return (tot[:-1] / tot[-1]).numpy()[None]


def train(
    data_root: "str | Path",
    out_dir: "str | Path",
    cfg: TrainConfig,
    progress: bool = True,
    log=lambda m: None,
    stop_after: int | None = None,
) -> dict | None:
    """Train a surrogate on the dataset in ``data_root``, or resume the run in ``out_dir``.
    ``stop_after``: leave this call after that many steps (as an interruption would; the
    next call resumes). Under torchrun, every rank calls it (see the module docstring) and
    the ranks other than 0 return None."""
    out_dir = Path(out_dir)
    parallel.set_threads(cfg.threads)
    resolve_device(cfg.device)  # a GPU that is not there is refused before the folder is claimed
    state_path = out_dir / "state.pt"
    # another run's folder is not written into (checked by every rank before they meet, so
    # before rank 0 writes anything)
    # (a run stopped before its first checkpoint leaves only tb/: it starts again there)
    claim_out_dir(out_dir, "surrogate training", {"tb"}, marker="state.pt")
    ranks = parallel.setup(cfg.device)
    device, W = ranks.device, ranks.world
    if not ranks.is_main:
        progress, log = False, (lambda m: None)
    resumed = None
    if state_path.exists():
        resumed = load_plain(state_path, "surrogate training state")
        if not isinstance(resumed, dict) or not isinstance(resumed.get("config"), dict):
            raise InputError(f"{state_path}: not a surrogate training state; use another --out")
        old = resumed["config"]
        defaults = TrainConfig()
        diff = [k for k in _FIXED if old.get(k, getattr(defaults, k)) != getattr(cfg, k)]
        if diff:
            raise InputError(
                f"{state_path}: this run was started with other settings ({', '.join(diff)}); "
                f"use the same options or another --out"
            )
        log(f"resuming {state_path} at step {resumed.get('step')}")

    designs, man = design_indices(data_root, cfg.max_designs or None)
    if resumed is not None:
        old_data = resumed.get("data")
        if not isinstance(old_data, dict) or "designs_csv_sha256" not in old_data:
            raise InputError(
                f"{state_path}: damaged surrogate training state (no data record); remove it to train from the start"
            )
        if old_data["designs_csv_sha256"] != man["designs_csv_sha256"]:
            raise InputError(f"{state_path}: that run trained on another dataset than {data_root}")
    tr_designs, va_designs, mine = rank_designs(designs, cfg.val_designs, cfg.seed, ranks.rank, W)
    arrays, man = load_arrays(
        data_root, cfg.psf, cfg.bin, designs=np.concatenate([mine, va_designs]) if ranks.is_main else mine
    )
    in_train = np.isin(arrays.design, mine)
    train_t = to_tensors(arrays.subset(np.flatnonzero(in_train)), device)
    val_t = to_tensors(arrays.subset(np.flatnonzero(~in_train)), device) if ranks.is_main else None
    data_meta = {
        "root": str(Path(data_root).resolve()),
        "designs_csv_sha256": man["designs_csv_sha256"],
        "n_train_designs": int(len(tr_designs)),
        "n_val_designs": int(len(va_designs)),
        "val_designs": va_designs.tolist(),
    }
    del arrays

    torch.manual_seed(cfg.seed)
    model = build_model(cfg, man, _vignetting_mean(train_t["vignetting"].cpu(), ranks), {"data": data_meta}).to(device)
    opt = torch.optim.Adam(model.net.parameters(), lr=cfg.lr)
    gen = torch.Generator(device="cpu").manual_seed(cfg.seed)
    step, seconds, history = 0, 0.0, []
    if cfg.init and not resumed:
        _start_from(model, cfg.init)
        log(f"starting from the weights of {cfg.init}")
    if resumed:
        try:
            parallel.check_finite_weights(resumed["model"], state_path)
            model.net.load_state_dict(resumed["model"])
            opt.load_state_dict(resumed["optimizer"])
            gen.set_state(resumed["generator"])
            step, seconds, history = int(resumed["step"]), float(resumed["seconds"]), list(resumed["history"])
            if not (0 <= step <= MAX_STEPS and math.isfinite(seconds) and seconds >= 0):
                raise InputError(f"step {step}, seconds {seconds}")
        except DAMAGED_STATE_ERRORS as err:
            raise InputError(
                f"{state_path}: damaged surrogate training state ({type(err).__name__}: "
                f"{' '.join(str(err).split())}); remove it to train from the start"
            ) from None
    model.train()
    net = model.net
    if ranks.distributed:  # averages the gradients over the ranks in backward
        from torch.nn.parallel import DistributedDataParallel

        net = DistributedDataParallel(model.net, device_ids=[device.index] if device.type == "cuda" else None)
    writer = tensorboard_writer(out_dir / "tb") if ranks.is_main else None
    n_tr, k = len(tr_designs), len(man["fields_deg"])
    fields = model.fields
    bar = tqdm(total=cfg.steps, initial=step, desc="train surrogate", unit="step", disable=not progress)
    t_start = time.time() - seconds
    first_step = step

    def checkpoint(val: dict | None) -> None:
        meta = {
            "data": data_meta,
            "training": {
                "config": asdict(cfg),
                "steps_done": step,
                "seconds": round(time.time() - t_start, 1),
                "device": str(device),
                "val": val,
            },
        }
        model.save(out_dir / "surrogate.pt", **meta)
        save_atomic(
            {
                "config": asdict(cfg),
                "model": model.net.state_dict(),
                "optimizer": opt.state_dict(),
                "generator": gen.get_state(),
                "step": step,
                "seconds": time.time() - t_start,
                "history": history,
                "data": data_meta,
            },
            state_path,
        )

    while step < cfg.steps:
        # the global batch, the same on every rank; this rank computes the samples of its designs
        d = torch.randint(n_tr, (cfg.batch,), generator=gen)
        f = torch.randint(k, (cfg.batch,), generator=gen)
        own = d % W == ranks.rank
        d, f = (d[own] // W).to(device), f[own].to(device)
        psf, vig = net(model.normalize(train_t["params"][d]), fields[f])
        if len(d):
            terms = optics_loss_terms(psf, vig, train_t["psf"][d, f], train_t["vignetting"][d, f])
        else:  # none of this global batch's samples is in this rank's designs: a zero share
            terms = dict.fromkeys(("pixel", "fourier", "gradient", "vignetting"), psf.sum() * 0 + vig.sum() * 0)
        share = len(d) / cfg.batch  # this rank's part of the global batch mean
        loss = cfg.weights.total(terms) * share
        # every rank stops at the same step if any rank's loss left the finite numbers
        finite = bool(torch.isfinite(loss.detach()))
        if float(parallel.all_sum(torch.tensor([0.0 if finite else 1.0]), ranks)[0]) > 0:
            parallel.stop_if_diverged(step + 1, state_path, "lower --lr", loss=math.nan if finite else loss.detach())
        opt.zero_grad(set_to_none=True)
        (loss * W).backward()  # DistributedDataParallel divides the summed gradients by W
        torch.nn.utils.clip_grad_norm_(model.net.parameters(), cfg.clip_grad)
        elapsed = time.time() - t_start
        if cfg.minutes:  # rank 0's clock, so that every rank anneals and stops alike
            elapsed = parallel.broadcast_value(elapsed, ranks)
        lr = _lr(cfg, step, elapsed)
        for group in opt.param_groups:
            group["lr"] = lr
        opt.step()
        step += 1
        out_of_time = cfg.minutes and elapsed > 60 * cfg.minutes
        interrupted = stop_after is not None and step - first_step >= stop_after
        validating = step % cfg.val_every == 0 or step >= cfg.steps or out_of_time or interrupted
        if step % 10 == 0 or validating:  # the global batch's loss and terms (a collective call)
            names = list(terms)
            glob = parallel.all_sum(torch.stack([loss.detach()] + [terms[n].detach() * share for n in names]), ranks)
            loss_g, terms_g = float(glob[0]), {n: float(v) for n, v in zip(names, glob[1:])}
        if writer is not None and step % 10 == 0:
            writer.add_scalar("train/loss", loss_g, step)
            for name, v in terms_g.items():
                writer.add_scalar(f"train/{name}", v, step)
            writer.add_scalar("train/lr", lr, step)
        bar.update(1)
        if step % 50 == 0:
            bar.set_postfix(loss=f"{loss_g:.4f}", l1=f"{terms_g['pixel']:.4f}")
        if validating:  # every rank (their weights are the same), so all stop together
            parallel.stop_if_diverged(step, state_path, "lower --lr", surrogate=model.net)
        if validating and ranks.is_main:
            val = validate(model, val_t)
            for name, v in val.items():
                writer.add_scalar(f"val/{name}", v, step)
            history.append({"step": step, "seconds": round(time.time() - t_start, 1), "loss": loss_g, **val})
            checkpoint(val)
            writer.flush()
        if out_of_time or interrupted:
            break
    bar.close()
    summary = {
        "steps_done": step,
        "seconds": round(time.time() - t_start, 1),
        "device": str(device),
        "processes": W,
        "config": asdict(cfg),
        "data": {k2: v for k2, v in data_meta.items() if k2 != "val_designs"},
        "final_val": history[-1] if history else None,
        "history": history,
    }
    if ranks.is_main:
        writer.close()
        write_record_atomic(out_dir / "train.json", summary)
    parallel.barrier(ranks)  # the files are written when any rank returns
    return summary if ranks.is_main else None


def config_from_options(**opts) -> TrainConfig:
    names = {f.name for f in dc_fields(TrainConfig)}
    return TrainConfig(**{k: v for k, v in opts.items() if k in names and v is not None})
