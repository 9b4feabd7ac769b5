"""The differentiable optics stage f_OPTIC of the pipeline (paper Eq. 2 and Sec. 4.1): lens
parameters -> surrogate -> spatially varying render.

The lens parameters are ``nn.Parameter``s kept inside the surrogate's training ranges by a
sigmoid reparameterization: each value is

    p = lo + (hi - lo) * sigmoid(u),

with ``u`` the free, unconstrained parameter the optimizer moves. Any u gives a p strictly
inside [lo, hi], so the surrogate never extrapolates, and the gradient dp/du =
(hi - lo) s (1 - s) fades towards the bounds instead of stopping at a wall (the
paper's ranges are manufacturing tolerances: a design at a bound is allowed, beyond it not).
``values`` / ``set_values`` work in the parameters' own units.

``backend``: "surrogate" (the network, the paper's way) or "exact" (the engine's PSFs and
central-difference gradients, optics/exact.py: the same pipeline with no network; the
surrogate file then only says on whose terms, its space, fields, settings and ranges).
``backend`` can be switched on a live module (the hybrid runs of camera_design/hybrid.py do).

The image is in sensor pixels at the surrogate's PSF pitch (5.86 um for the shipped
paper-triplet-v1 surrogate); the K fields span the axis to ``full_field_px`` pixels from the
image centre (the half-diagonal by default: the corners see the lens's full field).
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import InputError
from ..surrogate.checkpoint import OpticsSurrogate
from .render import render


class DifferentiableOptics(nn.Module):
    """image [B, C, H, W] (scene radiance, linear) -> image through the lens [B, C, H, W].

    ``init``: raw starting values [P] (default: the base lens of the surrogate's space, or
    the middle of each range where the base lies outside it). The surrogate's weights are
    frozen (``requires_grad=False``); only the lens parameters learn."""

    def __init__(
        self,
        surrogate: "OpticsSurrogate | str",
        init=None,
        *,
        patch: int = 64,
        full_field_px: float | None = None,
        eps: float = 1e-4,
        backend: str | None = None,
    ):
        super().__init__()
        if not isinstance(surrogate, OpticsSurrogate):
            surrogate = OpticsSurrogate.load(surrogate)
        self.surrogate = surrogate.eval()
        for p in self.surrogate.parameters():
            p.requires_grad_(False)
        self.patch, self.full_field_px, self.eps = patch, full_field_px, eps
        self.register_buffer("lo", surrogate.param_min.float().clone())
        self.register_buffer("hi", surrogate.param_max.float().clone())
        self.u = nn.Parameter(torch.zeros(len(surrogate.param_names)))
        self.set_values(self.base_values() if init is None else init)
        # where the K fields land on the sensor, as fractions of the full field's image height
        # (None: proportional to the field angle); see camera.stages.image_height_fractions. A
        # buffer, so it moves with the module (not saved: the run sets it when it builds the camera)
        self.register_buffer("render_fields", None, persistent=False)
        self._exact = None
        # the exact optics' lens gradient (optics/exact.py EXACT_GRADIENTS), set before first use
        self.exact_gradient = "one-pass"
        # default: the network where there is one (a copy on another space's terms has none)
        self.backend = backend or ("surrogate" if surrogate.has_network else "exact")
        # an additive correction of the surrogate's output (psf [K, C, S, S], vignetting [K, C]):
        # exact minus surrogate at an anchor design (camera_design/hybrid.py); None: the network alone
        self.correction: tuple[torch.Tensor, torch.Tensor] | None = None
        # the fields the renderer uses (indices into the K trained fields; None: all of them)
        self.field_index: list[int] | None = None

    @property
    def backend(self) -> str:
        return self._backend

    @backend.setter
    def backend(self, name: str) -> None:
        if name not in ("surrogate", "exact"):
            raise InputError(f"optics backend must be surrogate or exact, got {name!r}")
        if name == "surrogate" and not self.surrogate.has_network:
            raise InputError(f"optics backend surrogate: {self.surrogate.no_network_why}")
        self._backend = name

    @property
    def exact(self):
        """The engine on the surrogate's terms (optics.exact.ExactOptics), made on first use."""
        if self._exact is None:
            from .exact import ExactOptics

            self._exact = ExactOptics.from_surrogate(self.surrogate, gradient=self.exact_gradient)
        return self._exact

    @property
    def names(self) -> list[str]:
        return self.surrogate.param_names

    def base_values(self) -> torch.Tensor:
        """The base lens's values of the space's parameters (mid-range where outside the range)."""
        from ..dataset.manifest import space_and_base

        man = self.surrogate.manifest
        if not man:
            return (self.lo + self.hi) / 2
        space, base = space_and_base(man)
        v = torch.tensor(space.values(base.data), dtype=torch.float32, device=self.lo.device)
        inside = (v >= self.lo) & (v <= self.hi)
        return torch.where(inside, v, (self.lo + self.hi) / 2)

    def values(self) -> torch.Tensor:
        """Lens parameters [P] in their units (differentiable w.r.t. ``u``)."""
        return self.lo + (self.hi - self.lo) * torch.sigmoid(self.u)

    @torch.no_grad()
    def set_values(self, values) -> None:
        """Set the parameters (raw units); values outside the ranges (the surrogate's, or the
        space it was put in: OpticsSurrogate.in_space) are an error naming them."""
        from ..surrogate.checkpoint import SurrogateRangeError, outside_ranges

        v = torch.as_tensor(values, dtype=torch.float32).to(self.lo.device).reshape(-1)
        if v.numel() != self.lo.numel():
            raise InputError(f"{v.numel()} lens values for {self.lo.numel()} parameters")
        nonfinite, cols = outside_ranges(v, self.lo, self.hi)
        if nonfinite or cols:
            raise SurrogateRangeError(
                "lens values outside the ranges: "
                + "; ".join(
                    [f"{self.names[j]} = {float(v[j]):.6g}" for j in nonfinite]
                    + [
                        f"{self.names[j]} = {x:.6g} outside [{float(self.lo[j]):.6g}, {float(self.hi[j]):.6g}]"
                        for j, x, _ in cols
                    ]
                )
            )
        t = ((v - self.lo) / (self.hi - self.lo)).clamp(self.eps, 1 - self.eps)
        self.u.copy_(torch.log(t) - torch.log1p(-t))

    def f_number(self) -> torch.Tensor | None:
        """The lens's f-number where the space has it as a parameter (``f_number``, EFL held:
        the detection space), differentiable w.r.t. ``u``; None where the aperture is fixed."""
        names = self.surrogate.param_names
        return self.values()[names.index("f_number")] if "f_number" in names else None

    @torch.no_grad()
    def range_step_scale(self, values=None) -> torch.Tensor:
        """Per-parameter factors [P] on an optimizer's step in ``u`` that make the step the
        same fraction of every range at ``values`` (raw units; default: the current lens),
        wherever in its range each value sits (``DesignConfig.lens_steps = "range"``).

        Adam moves u by about lr per step; the value then moves (hi - lo) s (1 - s) lr, with
        s = sigmoid(u): a quarter of lr of the range at mid-range, less towards a bound. A start
        at 0.89 of its range (the detection space's f/4.4 in f/2.8-4.6) moves 2.5x slower than
        one in the middle, in both directions. The factor 1 / (4 s (1 - s)) evens that out at
        ``values``, capped at ``cap`` (a start within 7 % of a bound moves at most 4x its
        sigmoid pace); as the lens travels the sigmoid still slows it towards a bound."""
        cap = 4.0
        v = self.values() if values is None else torch.as_tensor(values, dtype=self.lo.dtype).to(self.lo.device)
        s = ((v - self.lo) / (self.hi - self.lo)).clamp(self.eps, 1 - self.eps)
        return (1.0 / (4.0 * s * (1.0 - s))).clamp(max=cap)

    def psfs(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(psf [K, C, S, S] unit sum per channel, vignetting [K, C]) at the current parameters,
        from the backend (exact: the engine, gradients by its one-pass gradient or differences)."""
        if self._backend == "exact":
            from .exact import exact_psfs

            return exact_psfs(self.values(), self.exact)
        return self._surrogate_psfs()

    def _surrogate_psfs(self, index: list[int] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        # inside the ranges by construction: no per-step range check (a device-to-host copy)
        psf, vig = self.surrogate.psfs(self.values(), check=False, field_index=index)
        if self.correction is not None:
            # exact at the anchor; away from it the surrogate's change (kept a non-negative unit-sum PSF)
            dp, dv = self.correction if index is None else (self.correction[0][index], self.correction[1][index])
            psf = (psf + dp).clamp_min(0.0)
            psf = psf / psf.sum((-2, -1), keepdim=True).clamp_min(1e-12)
            vig = vig + dv
        return psf, vig

    @property
    def fields(self) -> torch.Tensor:
        return self.surrogate.fields

    @property
    def psf_size(self) -> int:
        return int(self.surrogate.cfg.psf_size)

    def train(self, mode: bool = True):
        super().train(mode)
        self.surrogate.eval()  # frozen: never in training mode
        return self

    def use_fields(self, k: int) -> None:
        """Render from k of the K trained fields, spread evenly from the axis to the full field
        (always both ends; k = 0 or K: all). Fewer fields: fewer surrogate evaluations per step,
        a coarser interpolation of the PSF along the field."""
        n = len(self.surrogate.fields_deg)
        if k < 0 or k == 1 or k > n:
            raise InputError(f"field samples: 0 (all {n}) or 2..{n}, got {k}")
        self.field_index = None if k in (0, n) else sorted({round(i * (n - 1) / (k - 1)) for i in range(k)})

    def forward(self, image: torch.Tensor, offset_px: tuple[float, float] = (0.0, 0.0)) -> torch.Tensor:
        """offset_px: a crop's centre from the optical axis (rows, columns; needs ``full_field_px``)."""
        fields = self.fields if self.render_fields is None else self.render_fields
        if self.field_index is None:
            psf, vig = self.psfs()
        elif self._backend == "surrogate":  # only the fields rendered are evaluated
            psf, vig = self._surrogate_psfs(self.field_index)
            fields = fields[self.field_index]
        else:  # the engine computes every field of the dataset anyway
            psf, vig = self.psfs()
            psf, vig, fields = psf[self.field_index], vig[self.field_index], fields[self.field_index]
        return render(image, psf, fields, vig, patch=self.patch, full_field_px=self.full_field_px, offset_px=offset_px)

    def exact_psfs(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The exact engine's (psf, vignetting) for the current parameters, computed as the
        surrogate's training data was; ``render(image, *exact_psfs(), fields)`` checks a
        result against the real optics."""
        from ..surrogate.ground_truth import exact_optics

        ex = exact_optics(self.surrogate, self.values().detach().double().cpu().numpy()[None])
        return ex["psf"][0], ex["vignetting"][0]
