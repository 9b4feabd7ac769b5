"""A trained surrogate as one object and one file: the network, the normalization statistics
of its inputs, the parameter ranges it was trained on, its field positions and output pitch,
and the manifest of the dataset it learned from.

``OpticsSurrogate`` takes raw lens parameter values (the space's units), normalizes them
with the training designs' mean and standard deviation (paper Sec. 4.1) and checks them
against the space's ranges: outside them the network extrapolates, so by default that is an
error naming the parameter (``out_of_range="warn"`` warns instead, ``"ignore"`` says
nothing).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import InputError
from ..io import save_atomic
from ..lens import BUNDLED_SURROGATES
from ..torchfile import build_module, load_plain
from .model import SurrogateConfig, SurrogateNet

FORMAT = "optix-surrogate/1"
BUNDLED = BUNDLED_SURROGATES


class SurrogateRangeError(InputError):
    """Lens parameters outside the ranges the surrogate was trained on."""


class SurrogateFileError(InputError):
    """A checkpoint that cannot be read or is not a surrogate; the message names the file."""


def bundled_path(name: str) -> Path:
    return Path(__file__).resolve().parent.parent / "bundled" / BUNDLED[name]


def resolve(spec: "str | Path") -> Path:
    """A checkpoint path, or the name of a shipped surrogate (``paper-triplet-v1``)."""
    if str(spec) in BUNDLED:
        return bundled_path(str(spec))
    p = Path(spec)
    if p.is_dir():
        p = p / "surrogate.pt"
    if not p.is_file():
        names = ", ".join(BUNDLED)
        raise SurrogateFileError(f"{spec}: no such surrogate file (or a shipped one: {names})")
    return p


def outside_ranges(values, lo, hi) -> tuple[list[int], list[tuple[int, float, int]]]:
    """Parameter values [N, P] (or [P]) against ranges ``lo`` .. ``hi`` [P], with a tolerance of
    1e-6 of each range: (the columns holding a non-finite value, [(column, its first finite
    value outside, how many rows are outside)])."""
    lo, hi = torch.as_tensor(lo).cpu().double(), torch.as_tensor(hi).cpu().double()
    p = torch.as_tensor(values).detach().to("cpu", torch.float64).reshape(-1, lo.numel())
    tol = 1e-6 * (hi - lo)
    bad = ((p < lo - tol) | (p > hi + tol)) & torch.isfinite(p)  # [N, P]; non-finite apart
    nonfinite = torch.nonzero((~torch.isfinite(p)).any(0)).flatten().tolist()
    cols = [(j, float(p[bad[:, j], j][0]), int(bad[:, j].sum())) for j in torch.nonzero(bad.any(0)).flatten().tolist()]
    return nonfinite, cols


def _same_specification(lens: dict, own: dict, where: str) -> None:
    """A lens may take a surrogate's terms (PSF window, sampling, fields, sensor) only at the
    specification they were made for: the same aperture, field angles and wavelengths."""
    for key in ("aperture", "fields_deg", "wavelengths_nm", "primary_wavelength_nm"):
        if lens.get(key) != own.get(key):
            raise InputError(
                f"{where}: its base lens {lens.get('name', '?')} differs from {own.get('name', '?')} "
                f"(whose terms it would take) in {key}: {lens.get(key)!r} vs {own.get(key)!r}"
            )


class OpticsSurrogate(nn.Module):
    """Raw lens parameters [B, P] + normalized field [B] -> (psf [B, C, S, S] unit sum,
    vignetting [B, C]). ``psfs(params)`` gives every trained field at once for the renderer."""

    def __init__(
        self,
        cfg: SurrogateConfig,
        *,
        param_names,
        param_mean,
        param_std,
        param_min,
        param_max,
        fields_deg,
        pitch_um: float,
        psf_kind: str = "psf_sensor",
        bin: int = 1,
        channel_names=("R", "G", "B"),
        manifest: dict | None = None,
        meta: dict | None = None,
    ):
        super().__init__()
        self.net = SurrogateNet(cfg)
        self.cfg = cfg
        self.param_names = list(param_names)
        if len(self.param_names) != cfg.n_params:
            raise InputError(f"{len(self.param_names)} parameter names for a {cfg.n_params}-parameter network")
        std = np.asarray(param_std, float)
        self.register_buffer("param_mean", torch.as_tensor(np.asarray(param_mean, float), dtype=torch.float32))
        self.register_buffer("param_std", torch.as_tensor(np.where(std > 0, std, 1.0), dtype=torch.float32))
        self.register_buffer("param_min", torch.as_tensor(np.asarray(param_min, float), dtype=torch.float64))
        self.register_buffer("param_max", torch.as_tensor(np.asarray(param_max, float), dtype=torch.float64))
        self.fields_deg = [float(f) for f in fields_deg]
        self.register_buffer(
            "fields", torch.tensor(self.fields_deg, dtype=torch.float32) / max(max(self.fields_deg), 1e-12)
        )
        self.pitch_um = float(pitch_um)
        self.psf_kind, self.bin = psf_kind, int(bin)
        self.channel_names = list(channel_names)
        self.manifest = manifest or {}
        self.meta = meta or {}
        self.out_of_range = "error"
        # False on a copy put in a space of other parameters (in_space(network=False)): terms only
        self.has_network = True
        self.no_network_why = ""

    # -- inputs -------------------------------------------------------------------------
    def normalize(self, params: torch.Tensor) -> torch.Tensor:
        return (params.to(self.param_mean) - self.param_mean) / self.param_std

    def check_params(self, params, mode: str | None = None) -> list[str]:
        """Problems of raw parameter values [..., P] against the training ranges; raises
        :class:`SurrogateRangeError` (mode "error"), warns ("warn") or only returns them."""
        mode = mode or self.out_of_range
        if mode not in ("error", "warn", "ignore"):
            raise InputError(f"out_of_range must be error, warn or ignore, got {mode!r}")
        lo, hi = self.trained_min.cpu(), self.trained_max.cpu()
        rows = torch.as_tensor(params).reshape(-1, self.cfg.n_params).shape[0]
        nonfinite, cols = outside_ranges(params, lo, hi)
        problems = ["non-finite parameter values"] if nonfinite else []
        for j, v, n in cols:
            problems.append(
                f"{self.param_names[j]} = {v:.6g} outside its training range "
                f"[{float(lo[j]):.6g}, {float(hi[j]):.6g}]" + (f" ({n} rows)" if rows > 1 else "")
            )
        self._complain(problems, mode, "(the network would extrapolate)")
        return problems

    @property
    def trained_min(self) -> torch.Tensor:
        """The lower ends of the ranges the network learned (``param_min`` unless put in
        another space by :meth:`in_space`)."""
        return self._trained[0] if getattr(self, "_trained", None) else self.param_min

    @property
    def trained_max(self) -> torch.Tensor:
        return self._trained[1] if getattr(self, "_trained", None) else self.param_max

    @staticmethod
    def _complain(problems: list[str], mode: str, why: str) -> None:
        if problems and mode != "ignore":
            msg = "surrogate input: " + "; ".join(problems) + " " + why
            if mode == "error":
                raise SurrogateRangeError(msg)
            warnings.warn(msg, stacklevel=4)

    def in_space(self, space, base, source: str | None = None, *, network: bool = True) -> "OpticsSurrogate":
        """This surrogate on the terms of a wider (or other) ``space`` over the same parameters
        and base lens: a copy whose manifest records that space (its ranges become the design
        ranges every design tool reads: the optics' sigmoid bounds, the exact engine's, the
        guard's and the final checks') and the space it was trained on as ``trained_space``.
        Outside its training ranges the network extrapolates: the copy does not refuse them
        (``out_of_range = "ignore"``; ``check_params`` still lists them, against ``trained_min``
        and ``trained_max``): use it with exact optics (camera_design's ``space``).
        ``base``: the space's base lens (a Lens or dict), which must be the surrogate's.

        ``network=False``: a space over other parameters of the same base lens (the detection
        space with free centre thicknesses, issue 35), or of another lens at the same
        specification (the two-element paper-doublet, issue 57: the same f-number, fields and
        wavelengths, so the same PSF window, sampling and sensor): the copy gives only the terms
        (fields, PSF window and sampling, sensor pitch, base lens, limits) for exact optics, and
        has no network (``has_network`` False; ``psfs`` and ``forward`` are an error saying so)."""
        import copy

        from ..dataset.manifest import space_and_base

        if not self.manifest:
            raise InputError("the surrogate has no dataset manifest: it cannot be put in another space")
        trained, own_base = space_and_base(self.manifest)
        where = source or space.source
        same = space.names == trained.names
        if not same and network:
            raise InputError(
                f"{where}: its parameters ({', '.join(space.names)}) are not the surrogate's "
                f"({', '.join(trained.names)}), in the same order"
            )
        base_data = base.data if hasattr(base, "data") else base
        other_lens = base_data != own_base.data
        if other_lens and network:
            raise InputError(f"{where}: its base lens is not the surrogate's ({own_base.name})")
        if other_lens:
            _same_specification(base_data, own_base.data, where)
        mine = {p.name: (p.kind, p.surface) for p in space.params}
        if not other_lens and any(mine.get(p.name, (p.kind, p.surface)) != (p.kind, p.surface) for p in trained.params):
            raise InputError(f"{where}: its parameters change other surfaces than the surrogate's of the same names")
        if space.constraints and "sampling_summary" in self.manifest:
            limits = self.manifest["sampling_summary"].get("limits") or {}
            other = {k: v for k, v in space.constraints.items() if k in limits and float(limits[k]) != float(v)}
            if other:
                raise InputError(
                    f"{where}: its limits {other} are not those of the surrogate's dataset {limits}; "
                    "the guard and the final checks use one set"
                )
        man = copy.deepcopy(self.manifest)
        man["trained_space"] = man["space"]
        man["space"] = {**man["space"], "source": where, "parameters": space.to_json()}
        if other_lens:
            man["space"]["lens"] = base_data.get("name", man["space"].get("lens"))
            man["base_lens"] = copy.deepcopy(base_data)
            man["terms_from"] = own_base.name
        # away from the nominal the dataset's coarse best-focus sampling (7 fields, 4 rings) is
        # off by up to 10 um: refocus every design on all the fields with 8 rings (the final
        # focus check's sampling)
        man["settings"] = {**man["settings"], "focus_fields": len(man["fields_deg"]), "focus_rings": 8}
        out = copy.copy(self)
        out._buffers = dict(self._buffers)
        lo = torch.tensor([p.min for p in space.params], dtype=torch.float64)
        hi = torch.tensor([p.max for p in space.params], dtype=torch.float64)
        out._trained = (self.trained_min, self.trained_max)  # what check_params reports against
        out.param_min, out.param_max = lo, hi
        out.manifest = man
        out.out_of_range = "ignore"
        if not same:
            added = [n for n in space.names if n not in trained.names]
            dropped = [n for n in trained.names if n not in space.names]
            out.param_names = list(space.names)
            out.has_network = False
            out.no_network_why = (
                f"the network learned the {len(trained.names)} parameters of {Path(str(trained.source)).stem}; {where} "
                + ", ".join(
                    x
                    for x in (
                        f"adds {', '.join(added)}" if added else "",
                        f"drops {', '.join(dropped)}" if dropped else "",
                        "orders them otherwise" if not (added or dropped) else "",
                    )
                    if x
                )
                + ": exact optics only"
            )
        return out

    def _need_network(self) -> None:
        if not self.has_network:
            raise InputError(f"no optics network on these terms: {self.no_network_why}")

    # -- outputs ------------------------------------------------------------------------
    def forward(self, params: torch.Tensor, field: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Raw params [B, P] (or [P]), normalized field [B] in [0, 1] -> (psf [B, C, S, S], vignetting [B, C])."""
        self._need_network()
        params = torch.as_tensor(params)
        if params.dim() == 1:
            params = params.unsqueeze(0)
        self.check_params(params)
        field = torch.as_tensor(field, dtype=self.param_mean.dtype, device=self.param_mean.device).reshape(-1)
        if field.numel() and (field.min() < -1e-6 or field.max() > 1 + 1e-6):
            self._complain(
                [f"field {float(field.min()):.4g}..{float(field.max()):.4g} outside [0, 1]"],
                self.out_of_range,
                "of the full field",
            )
        if field.numel() == 1 and params.shape[0] > 1:
            field = field.expand(params.shape[0])
        return self.net(self.normalize(params), field)

    def psfs(self, params: torch.Tensor, check: bool = True, field_index=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Every trained field of each design: raw params [P] or [B, P] -> (psf [(B,) K, C, S, S]
        unit sum per channel, vignetting [(B,) K, C]); the renderer's inputs (with ``fields``).
        ``check``: check the parameters against the training ranges (``out_of_range``).
        ``field_index``: only these of the K fields (a list of indices; the cost is per field)."""
        self._need_network()
        params = torch.as_tensor(params)
        single = params.dim() == 1
        p = params.reshape(-1, self.cfg.n_params)
        if check:
            self.check_params(p)
        fields = self.fields if field_index is None else self.fields[list(field_index)]
        b, k = p.shape[0], len(fields)
        psf, vig = self.net(self.normalize(p).repeat_interleave(k, 0), fields.repeat(b))
        psf = psf.reshape(b, k, *psf.shape[1:])
        vig = vig.reshape(b, k, -1)
        return (psf[0], vig[0]) if single else (psf, vig)

    # -- files --------------------------------------------------------------------------
    def state(self, half: bool = False) -> dict:
        sd = {k: (v.half() if half and v.is_floating_point() else v).cpu() for k, v in self.net.state_dict().items()}
        return {
            "format": FORMAT,
            "config": self.cfg.to_json(),
            "state_dict": sd,
            "half": half,
            "param_names": self.param_names,
            "param_mean": self.param_mean.tolist(),
            "param_std": self.param_std.tolist(),
            "param_min": self.param_min.tolist(),
            "param_max": self.param_max.tolist(),
            "fields_deg": self.fields_deg,
            "pitch_um": self.pitch_um,
            "psf_kind": self.psf_kind,
            "bin": self.bin,
            "channel_names": self.channel_names,
            "manifest": self.manifest,
            "meta": self.meta,
        }

    def save(self, path: "str | Path", half: bool = False, **meta) -> None:
        """Write atomically (temporary file, fsync, rename); ``half`` stores fp16 weights."""
        if meta:
            self.meta = {**self.meta, **meta}
        save_atomic(self.state(half), path)

    @classmethod
    def from_state(cls, st: dict, where: str = "<state>") -> "OpticsSurrogate":
        if not isinstance(st, dict) or st.get("format") != FORMAT:
            raise SurrogateFileError(f"{where}: not an {FORMAT} checkpoint")
        net = build_module(
            lambda **c: SurrogateNet(SurrogateConfig(**c)),
            st.get("config"),
            st.get("state_dict"),
            where,
            "surrogate checkpoint",
            SurrogateFileError,
        )
        numbers = {k: st.get(k) for k in ("param_mean", "param_std", "param_min", "param_max", "fields_deg")}
        numbers["pitch_um"] = [st.get("pitch_um")]
        for key, values in numbers.items():
            try:
                arr = np.asarray(values, dtype=float)
                ok = arr.ndim == 1 and arr.size > 0 and np.isfinite(arr).all()
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise SurrogateFileError(
                    f"{where}: damaged surrogate checkpoint: {key} is not a list of finite numbers"
                )
            if key.startswith("param_") and arr.size != net.cfg.n_params:
                raise SurrogateFileError(
                    f"{where}: damaged surrogate checkpoint: {arr.size} values in {key} "
                    f"for a {net.cfg.n_params}-parameter network"
                )
        lo, hi = np.asarray(st["param_min"], float), np.asarray(st["param_max"], float)
        mean, std = np.asarray(st["param_mean"], float), np.asarray(st["param_std"], float)
        # the normalization the network was trained with: a parameter that varies has a spread
        # inside its range, its mean inside the range (a zeroed or swapped record would feed the
        # network inputs it never saw, without a word)
        if (
            (lo > hi).any()
            or (std < 0).any()
            or ((hi > lo) & ~(std > 0)).any()
            or (std > (hi - lo) + 1e-9).any()
            or ((mean < lo - 1e-9) | (mean > hi + 1e-9)).any()
        ):
            raise SurrogateFileError(
                f"{where}: damaged surrogate checkpoint: param_min/param_max/param_mean/param_std "
                f"are not a range and a spread inside it"
            )
        if not float(st["pitch_um"]) > 0:
            raise SurrogateFileError(f"{where}: damaged surrogate checkpoint: pitch_um must be > 0")
        for key in ("manifest", "meta"):
            if not isinstance(st.get(key) or {}, dict):
                raise SurrogateFileError(f"{where}: damaged surrogate checkpoint: {key} is not a dict")
        try:
            m = cls(
                net.cfg,
                param_names=st["param_names"],
                param_mean=st["param_mean"],
                param_std=st["param_std"],
                param_min=st["param_min"],
                param_max=st["param_max"],
                fields_deg=st["fields_deg"],
                pitch_um=st["pitch_um"],
                psf_kind=st["psf_kind"],
                bin=st["bin"],
                channel_names=st["channel_names"],
                manifest=st.get("manifest"),
                meta=st.get("meta"),
            )
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise SurrogateFileError(f"{where}: damaged surrogate checkpoint ({type(exc).__name__}: {exc})") from None
        if m.manifest:  # the dataset record the design tools read: its space and base lens
            from ..dataset.manifest import space_and_base

            try:
                space_and_base(m.manifest)
            except (ValueError, TypeError, KeyError) as exc:
                raise SurrogateFileError(f"{where}: damaged surrogate checkpoint: {exc}") from None
        m.net = net
        return m

    @classmethod
    def load(cls, spec: "str | Path", map_location="cpu") -> "OpticsSurrogate":
        """A checkpoint file, a training directory (its surrogate.pt) or a shipped name."""
        path = resolve(spec)
        st = load_plain(path, "surrogate checkpoint", SurrogateFileError, map_location)
        m = cls.from_state(st.get("model", st) if isinstance(st, dict) else st, str(path))
        m.eval()
        return m
