"""The image-quality tasks in the design run (iq-software, iq-hardware, low-light; paper Sec. 6.1,
Tables 2-3): a camera of optics, sensor and ISP (the software ISP f_NN, or the hardware ISP's
hyperparameters through its proxy), the loss L1 + w LPIPS against the ideal rendering, the optics
model in the loop checked against the engine (``--optics``: surrogate, exact, hybrid, auto), and
the held-out evaluation: PSNR, SSIM, LPIPS, HaarPSI per image and position, both cameras under
each lens's exact PSFs (and, for reference, the surrogate's), and paired bootstrap intervals
(evaluate.py): the headline over the frame positions, the centre and the corner each apart
(``paired_by_position``).

Two more cameras hold the comparison (issue 54): ``nominal_untuned``, the nominal lens behind the
processing as it is before any fine-tuning (the pre-trained software ISP; the hardware ISP at its
default hyperparameters), and ``ideal_lens``, the baseline's processing fine-tuned on the same
budget behind a lens that blurs nothing and shades as the nominal does (build.delta_lens): the
ceiling of what a lens could add. The headline baseline is the better of ``nominal`` and
``nominal_untuned`` by mean headline PSNR (``headline_baseline``); the end-to-end camera is
paired against each of the two and against the ideal lens (``paired_against``)."""

from __future__ import annotations

import time
from pathlib import Path

import torch
from tqdm import tqdm

from ..camera import Camera, FixedOptics
from ..errors import InputError
from ..io import write_csv_atomic
from ..scenes import ImageFolder, bundled_photos
from ..scenes.corpus import PhotoCorpus
from ..surrogate.refine import RefineSettings
from ..tasks import heldout_set
from ..tasks.samples import POSITIONS, photo_test_set
from . import eval_cache
from . import evaluate as ev
from .build import build_camera, delta_lens
from .hybrid import OpticsMonitor, exact_gradient_steps, resolve_optics
from .outputs import save_panels
from .task_hooks import TaskHooks
from .training import LOSS_PARTS

WHO = ("nominal", "end_to_end")
TEST_PROTOCOL = "docs/test-split.md, written 2026-11-28 before the split's first use"
#: the two baselines the headline chooses between (``headline_baseline``)
BASELINES = ("nominal", "nominal_untuned")
#: what each camera of results.json is, in the printed summary
LABELS = {
    "nominal": "nominal lens + processing fine-tuned on the run's budget",
    "nominal_untuned": "nominal lens + processing not fine-tuned",
    "ideal_lens": "a lens that blurs nothing + processing fine-tuned on the same budget, the ceiling",
    "end_to_end": "end-to-end",
}
IDEAL_LENS_WHAT = (
    "a one-pixel PSF at every field with the nominal's relative illumination, through the renderer at the "
    "nominal's chief-ray heights (camera_design.build.delta_lens, as benches/lens_room.py --lens delta), "
    "behind the baseline's processing start fine-tuned on the same budget (make_optimizer 'nominal': the "
    "same schedule, updates per block, batches and noise seeds): the ceiling of what a lens could add"
)


def untuned_processing(task) -> str:
    """What the untuned baseline's processing is (results.json ``nominal_untuned.processing``)."""
    if task.isp == "hardware":
        return (
            "the hardware ISP at its default hyperparameters (isp.params.defaults: the out-of-the-box tuning; a "
            "default on a bound of its range sits 1e-6 of the range inside it), not the run's seeded random start "
            "(a start no one would ship), never tuned"
        )
    return "the pre-trained software ISP the run starts from (software_isp), not fine-tuned"


def headline_baseline(means: dict) -> dict:
    """The better of the two baselines (``BASELINES``) by mean headline PSNR on the held-out set
    (``means``: camera -> evaluate.summarize); a tie goes to ``nominal``, the paper's fair
    comparison. Chosen on the held-out set, against the end-to-end camera's interest: the
    end-to-end camera is compared with the stronger baseline."""
    n, u = (float(means[b]["psnr_db"]) for b in BASELINES)
    if u > n:
        name = "nominal_untuned"
        why = (
            f"higher mean headline PSNR on the held-out set: nominal_untuned {u:.4f} dB > nominal {n:.4f} dB "
            "(fine-tuning on the run's budget lowered it)"
        )
    else:
        name = "nominal"
        why = (
            f"higher or equal mean headline PSNR on the held-out set: nominal {n:.4f} dB >= nominal_untuned "
            f"{u:.4f} dB (fine-tuning on the run's budget raised it)"
        )
    return {
        "camera": name,
        "why": why,
        "rule": "the better of nominal and nominal_untuned by mean headline PSNR on the held-out set (a tie: nominal)",
        "psnr_db": {"nominal": n, "nominal_untuned": u},
    }


def _summary_or_none(rows: list | None) -> dict | None:
    return None if rows is None else ev.summarize(rows)


class ImageQualityHooks(TaskHooks):
    loss_parts = LOSS_PARTS

    def __init__(self, cfg, device="cpu"):
        super().__init__(cfg, device)
        self.mode, self.choice = resolve_optics(cfg)
        self.folder = ImageFolder(cfg.images) if cfg.images else None
        self.corpus = PhotoCorpus(cfg.photos, "train") if cfg.photos else None

    def check(self, sur, ranks):
        if not sur.has_network and self.mode != "exact":
            raise InputError(f"space {self.cfg.space}: {sur.no_network_why}; run it with --optics exact")
        if ranks.distributed and self.mode != "surrogate":
            raise InputError(
                f"--optics {self.cfg.optics} ({self.mode}) runs the engine inside the training steps, which is not "
                f"split over processes (exact is the image-quality tasks' default); under torchrun use --optics surrogate"
            )

    def describe(self):
        why = f" (auto: {self.choice['why']})" if self.cfg.optics == "auto" else ""
        return f"{super().describe()}, optics {self.mode}{why}"

    def build_camera(self, sur, frame, *, fixed_optics=None, trained=False):
        # a hybrid run refines its own copy of the surrogate
        own = trained and fixed_optics is None and self.mode == "hybrid"
        return build_camera(
            self.cfg, sur, fixed_optics=fixed_optics, frame=frame, own_surrogate=own, device=self.device
        )

    def monitor(self, camera, writer, log):
        c = self.cfg
        return OpticsMonitor(
            camera.optics,
            self.mode,
            c.check_every,
            c.hybrid_threshold,
            self.choice["refine"],
            RefineSettings(designs=c.refine_designs, steps=c.refine_steps, seed=c.seed),
            writer=writer,
            name="end_to_end",
            log=log,
        )

    def loss_at(self, camera, frame, ranks):
        return None  # training.train's default: the image-quality loss on training_batch (and --images)

    def nominal_optics(self, camera, sur, nominal_values, surrogate_psfs, frame):
        # the baseline trains through the same optics model as the run: the engine's PSFs of the
        # nominal lens where the run trusts the engine, the surrogate's where it does not
        psf, vig = surrogate_psfs
        if self.mode != "surrogate":
            psf, vig = (
                torch.as_tensor(a, dtype=torch.float32, device=nominal_values.device)
                for a in camera.optics.exact.psfs(nominal_values.double().cpu().numpy())
            )
        idx = camera.optics.field_index or list(range(len(sur.fields_deg)))
        return FixedOptics(
            psf[idx],
            vig[idx],
            camera.optics.render_fields[idx],
            patch=self.cfg.patch,
            full_field_px=frame.full_field_px,
        )

    def ideal_optics(self, sur, nominal_values, frame):
        return delta_lens(
            sur, nominal_values, patch=self.cfg.patch, full_field_px=frame.full_field_px, fallback=self.exact_fallback
        )

    def untuned_camera(self, sur, frame, nominal_optics):
        return build_camera(
            self.cfg, sur, fixed_optics=nominal_optics, frame=frame, device=self.device, untuned=True
        ).eval()

    def evaluate(self, run):
        c = self.cfg
        out, cams, optics, exact, frame, progress = run.out, run.cams, run.optics, run.exact, run.frame, run.progress
        samples = heldout_set(
            c.eval_size,
            exact["psf"].shape[-1] // 2,
            c.eval_procedural,
            c.eval_level,
            frame,
            positions=POSITIONS[c.eval_positions],
        )
        samples_key = eval_cache.samples_digest(samples)  # once per evaluation
        rows: dict[str, dict[str, list]] = {}
        reused_s = 0.0
        for who in WHO:
            rows[who] = {}
            for kind in ("exact", "surrogate"):
                if optics[who][kind] is None:
                    continue  # no network on this space's terms: the engine's optics only
                rows[who][kind], s = self._evaluate_behind(
                    out / f"eval_{who}_{kind}.json",
                    cams[who],
                    optics[who][kind],
                    frame,
                    samples,
                    samples_key,
                    "",
                    f"eval {who} ({kind} optics)",
                    progress,
                )
                reused_s += s
        # the further baselines, on the same samples and noise draws (``_own_optics``)
        extra = {who: v for who, v in _own_optics(cams, optics).items() if who not in WHO}
        for who, (kind, fo) in extra.items():
            rows[who] = {}
            rows[who][kind], s = self._evaluate_behind(
                out / f"eval_{who}_{kind}.json",
                cams[who],
                fo,
                frame,
                samples,
                samples_key,
                f"/{who}",
                f"eval {who} ({kind} optics)",
                progress,
            )
            reused_s += s
        return {"samples": samples, "rows": rows, "window": int(exact["psf"].shape[-1])}, reused_s

    def _evaluate_behind(self, path, cam, lens, frame, samples, samples_key, tag, desc, progress):
        """``cam``'s sensor and processing behind ``lens`` = (psf, vignetting, field heights) on
        ``samples``, cached in ``path`` under the camera's key (``tag`` tells cameras apart)."""
        psf, vig, fh = lens
        fo = FixedOptics(psf, vig, fh, patch=self.cfg.patch, full_field_px=frame.full_field_px).to(self.device)
        return _evaluate_cached(
            path,
            _camera_key(psf, vig, fh, cam.isp, cam.sensor, samples, samples_key, tag),
            Camera(fo, cam.sensor, cam.isp),
            samples,
            desc,
            progress,
        )

    def test_split(self, run, corpus, baseline):
        c = self.cfg
        out, cams, optics, evaluation, frame, progress = (
            run.out,
            run.cams,
            run.optics,
            run.evaluation,
            run.frame,
            run.progress,
        )
        samples = photo_test_set(
            corpus, c.eval_size, evaluation["window"] // 2, c.eval_level, frame, positions=POSITIONS[c.eval_positions]
        )
        samples_key = eval_cache.samples_digest(samples)
        rows = {}
        for who, (kind, fo) in _own_optics(cams, optics).items():
            rows[who], _ = self._evaluate_behind(
                out / f"test_{who}.json",
                cams[who],
                fo,
                frame,
                samples,
                samples_key,
                f"/test/{who}",
                f"test split: {who} ({kind} optics)",
                progress,
            )
        write_csv_atomic(
            out / "test_metrics.csv",
            (
                [who, r["image"], r["position"], r["radius"], *(r[m] for m in ev.METRICS)]
                for who, rs in rows.items()
                for r in rs
            ),
            header=["camera", "image", "position", "radius", *ev.METRICS],
        )
        paired = {}
        for who in rows:
            if who != "end_to_end":
                by = ev.paired_by_position(rows[who], rows["end_to_end"], c.bootstrap, c.seed)
                head = ev.headline_position(rows[who])
                paired[who] = {
                    "paired": by.get(head) or ev.paired(rows[who], rows["end_to_end"]),
                    "paired_by_position": by,
                }
        return {
            "protocol": TEST_PROTOCOL,
            "photos": corpus.record(),
            "n_images": len(corpus),
            "n_samples": len(samples),
            "positions": c.eval_positions,
            "headline_position": ev.headline_position(rows["end_to_end"]),
            "baseline": baseline,
            "baseline_why": "the headline baseline the held-out (development) set chose; no choice is made here",
            "means": {who: ev.summarize(rs) for who, rs in rows.items()},
            "paired_against": paired,  # end-to-end minus each camera, paired over the photographs
        }

    @torch.no_grad()
    def panels(self, run, path, n_images: int = 3):
        """target / nominal / end-to-end for three photos, at each held-out position."""
        c = self.cfg
        evaluation, cams, optics, frame = run.evaluation, run.cams, run.optics, run.frame
        samples = heldout_set(
            c.eval_size, evaluation["window"] // 2, 0, c.eval_level, frame, photos=bundled_photos()[:3]
        )
        names = []
        for s in samples:
            if s.name not in names:
                names.append(s.name)
        rows = []
        for s in samples:
            if s.name not in names[:n_images]:
                continue
            imgs = [s.target]
            for who in WHO:
                psf, vig, fh = optics[who]["exact"]
                cam = cams[who]
                fo = FixedOptics(psf, vig, fh, patch=cam.optics.patch, full_field_px=cam.optics.full_field_px)
                img, _ = Camera(fo.to(self.device), cam.sensor, cam.isp)(
                    s.scene[None].to(self.device),
                    s.offset_px,
                    torch.Generator().manual_seed(int(s.noise_seed)),
                    final=True,
                )
                imgs.append(img[0])
            rows.append((f"{s.name} ({s.position})", imgs))
        save_panels(path, rows, ["target", "nominal + fine-tuned processing", "end-to-end"])

    def summarize(self, run):
        rows, c = run.evaluation["rows"], self.cfg
        a, b = rows["nominal"], rows["end_to_end"]
        # each position paired apart, from the same rows; the headline (``paired``) is the frame's
        by_position = ev.paired_by_position(a["exact"], b["exact"], c.bootstrap, c.seed)
        head = ev.headline_position(a["exact"])

        def at_head(by: dict, base_rows: list) -> dict:
            return by[head] if head in by else ev.paired(base_rows, b["exact"], c.bootstrap, c.seed)

        res = {
            **{
                who: {**ev.summarize(rows[who]["exact"]), "surrogate": _summary_or_none(rows[who].get("surrogate"))}
                for who in WHO
            },
            "headline_position": head,
            "headline_position_why": (
                ev.HEADLINE_WHY
                if head == ev.HEADLINE_POSITION
                else f"eval_positions = {c.eval_positions} has no frame positions: the headline pairs all its samples"
            ),
            # end-to-end minus nominal (processing fine-tuned), as before the further baselines
            "paired": at_head(by_position, a["exact"]),
            "paired_by_position": by_position,
            "paired_by_zone": ev.paired_by_zone(a["exact"], b["exact"], c.bootstrap, c.seed),
            # None: no network on this space's terms (paper-doublet), the engine's optics only
            "paired_surrogate_optics": ev.paired(a["surrogate"], b["surrogate"], c.bootstrap, c.seed)
            if "surrogate" in a
            else None,
        }
        if "nominal_untuned" in rows:
            res["nominal_untuned"] = {
                **ev.summarize(rows["nominal_untuned"]["exact"]),
                "processing": untuned_processing(self.task),
            }
        if "ideal_lens" in rows:
            res["ideal_lens"] = {**ev.summarize(rows["ideal_lens"]["delta"]), "lens": IDEAL_LENS_WHAT}
        # end-to-end minus each baseline and minus the ideal lens (negative: below the ceiling): at
        # the headline position ("paired") and at each position apart, as the top-level keys
        own = {"nominal": "exact", "nominal_untuned": "exact", "ideal_lens": "delta"}
        res["paired_against"] = {}
        for who, kind in own.items():
            if who in rows:
                by = ev.paired_by_position(rows[who][kind], b["exact"], c.bootstrap, c.seed)
                res["paired_against"][who] = {"paired": at_head(by, rows[who][kind]), "paired_by_position": by}
        if "nominal_untuned" in rows:
            base = headline_baseline(res)
            res["baseline"] = {**base, "paired": res["paired_against"][base["camera"]]["paired"]}
        return res

    def held_out(self, run):
        samples, c = run.evaluation["samples"], self.cfg
        per_position = {p: POSITIONS[c.eval_positions].count(p) for p in dict.fromkeys(POSITIONS[c.eval_positions])}
        return {
            "n_images": len({s.name for s in samples}),
            "n_samples": len(samples),
            "positions": c.eval_positions,
            "per_image": len(POSITIONS[c.eval_positions]),
            "per_image_by_position": per_position,
            "headline_position": ev.HEADLINE_POSITION if ev.HEADLINE_POSITION in per_position else "all",
            "size_px": c.eval_size,
        }

    def extra(self, run, monitor, e2e):
        cams = run.cams
        res = {
            "optics_model": {
                **monitor.summary(),
                "requested": self.cfg.optics,
                "choice": self.choice,
                "exact_gradient_steps": exact_gradient_steps(e2e["history"]),
            }
        }
        if self.task.isp == "hardware":
            res["isp_hyperparameters"] = {who: cam.isp.hyperparameters() for who, cam in cams.items()}
        return res

    def write_tables(self, run):
        write_csv_atomic(
            run.out / "metrics.csv",
            (
                [who, kind, r["image"], r["position"], r.get("radius", ""), *(r[m] for m in ev.METRICS)]
                for who, kinds in run.evaluation["rows"].items()
                for kind, rs in kinds.items()
                for r in rs
            ),
            header=["camera", "optics", "image", "position", "radius", *ev.METRICS],
        )

    @staticmethod
    def summary_lines(res):
        e, h = res["end_to_end"], res["held_out"]
        head = res.get("headline_position", "all")
        where = (
            f"{h['per_image_by_position'][head]} {head} positions per image"
            if head in h.get("per_image_by_position", {})
            else f"{h['per_image']} positions per image"
        )
        base = res.get("baseline", {"camera": "nominal", "why": "the run has no untuned baseline"})
        name = base["camera"]
        against = res.get("paired_against") or {
            "nominal": {"paired": res["paired"], "paired_by_position": res.get("paired_by_position", {})}
        }
        p = against[name]["paired"]
        cams = [who for who in ("nominal", "nominal_untuned", "ideal_lens") if who in res]
        lines = [
            f"held-out ({h['n_images']} images; headline: {where}), exact optics:",
            f"  headline baseline: {name} ({base['why']}); diff = end-to-end minus {name}",
        ]
        for m, label in (("psnr_db", "PSNR dB"), ("ssim", "SSIM"), ("lpips", "LPIPS"), ("haarpsi", "HaarPSI")):
            lo, hi = p[m]["ci95"]
            means = "   ".join(f"{who} {res[who][m]:.4f}" for who in cams)
            lines.append(
                f"  {label:8s} {means}   end-to-end {e[m]:.4f}   diff {p[m]['mean']:+.4f} [{lo:+.4f}, {hi:+.4f}]"
            )
        lines.append("  (" + "; ".join(f"{who}: {LABELS[who]}" for who in cams) + ")")
        for who, pa in against.items():
            if who != name:
                d = pa["paired"]["psnr_db"]
                lines.append(
                    f"  PSNR dB  end-to-end minus {who} {d['mean']:+.4f} [{d['ci95'][0]:+.4f}, {d['ci95'][1]:+.4f}]"
                    + ("   (the ceiling: below zero, how far below it)" if who == "ideal_lens" else "")
                )
        for pos, pp in against[name]["paired_by_position"].items():
            if pos != head:
                lo, hi = pp["psnr_db"]["ci95"]
                lines.append(
                    f"  {pos:8s} PSNR dB {name} {res[name]['by_position'][pos]['psnr_db']:.4f}   end-to-end "
                    f"{e['by_position'][pos]['psnr_db']:.4f}   diff {pp['psnr_db']['mean']:+.4f} [{lo:+.4f}, {hi:+.4f}]"
                )
        t = res.get("test_split")
        if t:
            tb, tp = t["baseline"], t["paired_against"][t["baseline"]]["paired"]["psnr_db"]
            ti = t["paired_against"].get("ideal_lens", {}).get("paired", {}).get("psnr_db")
            lines.append(
                f"test split ({t['n_images']} photographs at native scale, {t['protocol']}): PSNR dB "
                + "   ".join(f"{who} {m['psnr_db']:.4f}" for who, m in t["means"].items())
            )
            lines.append(
                f"  end-to-end minus {tb} {tp['mean']:+.4f} [{tp['ci95'][0]:+.4f}, {tp['ci95'][1]:+.4f}]"
                + (f"; minus ideal_lens {ti['mean']:+.4f} [{ti['ci95'][0]:+.4f}, {ti['ci95'][1]:+.4f}]" if ti else "")
            )
        om = res["optics_model"]
        used, net = om["final_error_per_field"], om["final_network_error_per_field"]
        lines.append(
            f"optics model {om['mode']} ({om['choice']['why']}); PSF rel. L1 at the final design, worst field: "
            "the model the last steps used "
            + (f"{max(used):.4f}" if used else "-")
            + ", the network "
            + (f"{max(net):.4f}" if net else "none (no network learned this space)")
            + f"; {om['n_refinements']} refinements, {om['exact_gradient_steps']} lens steps on exact gradients"
        )
        return lines


def _own_optics(cams: dict, optics: dict) -> dict:
    """Each camera's optics for the evaluation: (kind, (psf, vignetting, field heights)). The two
    trained lenses and the nominal behind the untuned processing: their exact optics; the ideal
    lens: its own (a delta PSF; no other lens's PSFs apply to it)."""
    own = {who: ("exact", optics[who]["exact"]) for who in WHO}
    if "nominal_untuned" in cams:
        own["nominal_untuned"] = ("exact", optics["nominal"]["exact"])
    if "ideal_lens" in cams:
        fo = cams["ideal_lens"].optics
        own["ideal_lens"] = ("delta", (fo.psf, fo.vignetting, fo.fields))
    return own


def _camera_key(psf, vig, fh, isp, sensor, samples, samples_key: str, tag: str = "") -> str:
    """What a held-out evaluation depends on besides the run's settings (eval_cache): the
    camera's PSFs, vignetting, field heights, processing weights and sensor, the held-out
    samples (``samples_key``: eval_cache.samples_digest of ``samples``, computed once per
    evaluation) and the code."""
    return eval_cache.evaluation_key(
        f"samples={len(samples)}{tag}",
        samples=samples_key,
        sensor=eval_cache.sensor_digest(sensor),
        tensors=(psf, vig, fh, *isp.state_dict().values()),
    )


def _rows_ok(rows) -> bool:
    """Every row as ``evaluate.evaluate`` writes it (a hand-edited or damaged file is evaluated again)."""
    return isinstance(rows, list) and all(
        isinstance(r, dict)
        and isinstance(r.get("image"), str)
        and isinstance(r.get("position"), str)
        and all(isinstance(r.get(m), (int, float)) and not isinstance(r.get(m), bool) for m in ev.METRICS)
        and isinstance(r.get("radius"), (int, float))
        for r in rows
    )


def read_eval_cache(path: Path, key: str) -> dict | None:
    """An earlier evaluation of the same camera (None: absent, stale or damaged: evaluate again)."""
    cached = eval_cache.read(path, key)
    return cached if cached is not None and _rows_ok(cached.get("rows")) else None


def _evaluate_cached(path: Path, key: str, camera: Camera, samples, desc: str, progress: bool) -> tuple[list, float]:
    """(rows, seconds reused): the cached rows of the same camera, or a fresh evaluation, saved."""
    cached = read_eval_cache(path, key)
    if cached is not None:
        return cached["rows"], float(cached.get("wall_s", 0.0))
    t0 = time.perf_counter()
    rows = ev.evaluate(camera, tqdm(samples, desc=desc, unit="img", disable=not progress, leave=False))
    eval_cache.write(path, key, time.perf_counter() - t0, rows=rows)
    return rows, 0.0
