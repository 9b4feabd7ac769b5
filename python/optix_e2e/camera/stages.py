"""The camera's stages as torch modules with their parameter blocks (paper Eqs. 10-12).

Every stage says which of its parameters the end-to-end optimizer may move, as one named
block (``block()`` -> (name, parameters) or None), so Algorithm 1 can take turns over them:

* :class:`FixedOptics` - exact engine PSFs of one design (no block): the nominal lens in
  evaluation, or any design checked against the real optics.
* ``DifferentiableOptics`` (optics/) - the surrogate over the lens parameters (block "optics").
* :class:`SensorStage` - the EMVA 1288 sensor at one exposure and gain (no block): Poisson
  shot noise, dark current, read noise and quantisation on, seeded by the caller; in
  evaluation with common random numbers, so two cameras see the same noise draws.
* :class:`SoftwareISPStage` - the UNet f_NN (block "isp": its weights).
* :class:`HardwareISPStage` - the hardware ISP: its learned proxy in the loop, with the
  hyperparameters P_ISP as the block "isp" (kept in their ranges by a sigmoid); the true
  reference ISP at the same hyperparameters for evaluation (``reference``).
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import InputError
from ..isp import params as hp
from ..isp.proxy import ISPProxy
from ..isp.reference import ReferenceISP
from ..isp.software import SoftwareISP
from ..optics.render import render
from ..sensor import get_preset, simulate_raw
from ..sensor.emva import calibrate_radiance_scale
from ..sensor.spectral import aperture_gain


def image_height_fractions(lens_data: dict, fields_deg) -> torch.Tensor:
    """Where the chief rays of ``fields_deg`` (ascending, the last the full field) meet the
    image plane, as fractions of the last one's height: the renderer's field positions. With
    distortion they are not proportional to the field angle (the paper-triplet nominal's
    7.45 deg lands at 0.46 of its 14.9 deg height, not 0.5)."""
    from ..lens import Lens

    lens = Lens(lens_data, source="<design>")
    h = [0.0 if f == 0 else float(lens.wavefront(float(f))["chief_image_mm"][1]) for f in fields_deg]
    if not all(b > a for a, b in zip(h, h[1:])):
        raise InputError(f"chief-ray heights are not increasing with the field: {h}")
    return torch.tensor([x / h[-1] for x in h], dtype=torch.float32)


class FixedOptics(nn.Module):
    """Fixed PSFs [K, C, S, S] (unit sum per channel) and vignetting [K, C] at ``fields`` [K]:
    the same ``forward(image, offset_px)`` as DifferentiableOptics, nothing to learn.
    ``f_number``: the lens's, for a sensor whose photon count follows it (Eq. 3)."""

    def __init__(
        self,
        psf: torch.Tensor,
        vignetting: torch.Tensor,
        fields: torch.Tensor,
        *,
        patch: int = 64,
        full_field_px: float | None = None,
        f_number: float | None = None,
    ):
        super().__init__()
        self._f_number = None if f_number is None else float(f_number)
        self.register_buffer("psf", torch.as_tensor(psf, dtype=torch.float32))
        self.register_buffer("vignetting", torch.as_tensor(vignetting, dtype=torch.float32))
        self.register_buffer("_fields", torch.as_tensor(fields, dtype=torch.float32))
        self.patch, self.full_field_px = patch, full_field_px

    @property
    def fields(self) -> torch.Tensor:
        return self._fields

    @property
    def psf_size(self) -> int:
        return int(self.psf.shape[-1])

    def psfs(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.psf, self.vignetting

    def f_number(self) -> torch.Tensor | None:
        """The lens's f-number where the camera's photon count should follow it (None: the sensor preset's)."""
        return None if self._f_number is None else torch.tensor(self._f_number, device=self.psf.device)

    def block(self):
        return None

    def forward(self, image: torch.Tensor, offset_px=(0.0, 0.0)) -> torch.Tensor:
        return render(
            image,
            self.psf,
            self.fields,
            self.vignetting,
            patch=self.patch,
            full_field_px=self.full_field_px,
            offset_px=offset_px,
        )


class PerfectOptics(nn.Module):
    """A perfect lens: every point images to a point (the scene passes unchanged, no vignetting).

    Not the renderer behind a delta PSF: the renderer turns each PSF to its patch's azimuth by
    bilinear resampling (optics/render.py), which spreads a delta over its neighbours (45
    degrees keeps 74 % in the centre pixel), a blur no lens makes. ``psf_size`` only sets the
    margin the camera cuts, so a scene crop made for the real lens fits."""

    def __init__(self, psf_size: int, *, full_field_px: float | None = None):
        super().__init__()
        self._psf_size, self.full_field_px = int(psf_size), full_field_px

    @property
    def psf_size(self) -> int:
        return self._psf_size

    def block(self):
        return None

    def forward(self, image: torch.Tensor, offset_px=(0.0, 0.0)) -> torch.Tensor:
        return image


def calibrated_preset(
    preset="imx249", f_number: float | None = None, exposure_factor: float = 1.0, gain_factor: float = 1.0
):
    """The sensor preset for a lens of ``f_number``: its radiance scale set so that a white scene
    (linear 1.0) through that lens on the axis gives 85 % of full well in green at the preset's
    own exposure (the IMX249 at 5 ms, as the paper calibrates it); then exposure / gain scaled
    (low light: exposure_factor 1/100, gain_factor 100: the same mean DN, 100x fewer photons)."""
    p = get_preset(preset)
    if f_number is not None:
        p = p.with_(f_number=float(f_number))
        p = p.with_(radiance_scale=calibrate_radiance_scale(p))
    if exposure_factor != 1.0 or gain_factor != 1.0:
        p = p.with_(
            name=f"{p.name}-x{exposure_factor:g}-g{gain_factor:g}",
            exposure_s=p.exposure_s * exposure_factor,
            gain_dn_per_e=p.gain_dn_per_e * gain_factor,
        )
    return p


class SensorStage(nn.Module):
    """Linear radiance [B, 3, H, W] -> RAW [B, 1, H, W] in DN (Eq. 5), noise on unless ``noise=False``.

    ``common_noise=True`` (evaluation; not differentiable) draws the same noise for any two
    inputs given the same generator state (sensor.emva.raw_from_electrons), so two cameras
    seeded alike see the same noise draws."""

    def __init__(self, preset, noise: bool = True):
        super().__init__()
        self.preset, self.noise = get_preset(preset), noise

    def block(self):
        return None

    def forward(
        self,
        radiance: torch.Tensor,
        generator: torch.Generator | None = None,
        *,
        common_noise: bool = False,
        f_number: "torch.Tensor | float | None" = None,
    ) -> torch.Tensor:
        """``f_number``: the lens's (a tensor where the optics learn it): the photon count
        follows it by Eq. 3's 1 / (1 + (2N)^2) relative to the preset's f-number, which the
        preset's radiance scale was calibrated at (None: the preset's)."""
        if f_number is not None:
            f_number = torch.as_tensor(f_number, dtype=radiance.dtype, device=radiance.device)
            radiance = radiance * aperture_gain(f_number, self.preset.f_number)
        return simulate_raw(
            radiance,
            self.preset,
            noise=self.noise,
            quantize="uniform" if self.noise else "none",
            generator=generator,
            common_noise=common_noise,
        )


class SoftwareISPStage(nn.Module):
    """RAW -> sRGB through the software ISP f_NN (Eq. 11; isp/software.py: the classical
    pipeline calibrated for this camera's sensor plus a learned correction that sees where the
    crop lies in the frame); its weights are the block "isp"."""

    kind = "software"
    takes_position = True  # the camera passes the crop's offset and the frame's full field

    def __init__(self, net: SoftwareISP, preset=None):
        super().__init__()
        self.net = net if preset is None else net.calibrate(preset)

    def block(self):
        return "isp", list(self.net.parameters())

    def forward(self, raw: torch.Tensor, offset_px=(0.0, 0.0), full_field_px: float | None = None) -> torch.Tensor:
        return self.net(raw, offset_px, full_field_px)

    def final(self, raw: torch.Tensor, offset_px=(0.0, 0.0), full_field_px: float | None = None) -> torch.Tensor:
        """What the camera outputs in evaluation: the same network."""
        return self.forward(raw, offset_px, full_field_px)


class HardwareISPStage(nn.Module):
    """The hardware ISP: its proxy in the loop (weights frozen) with the hyperparameters P_ISP
    as the block "isp", each ``low + (high - low) sigmoid(logit)`` (inside its range by
    construction); :meth:`final` runs the true reference ISP at the current hyperparameters."""

    kind = "hardware"
    takes_position = True

    def __init__(
        self, proxy: ISPProxy, init_unit: torch.Tensor, pattern: str = "RGGB", adc_bits: int = 12, eps: float = 1e-3
    ):
        super().__init__()
        self.proxy = proxy.eval()
        self.proxy.requires_grad_(False)
        u = torch.as_tensor(init_unit, dtype=torch.float32).clamp(eps, 1 - eps)
        self.logit = nn.Parameter(torch.log(u) - torch.log1p(-u))
        self.reference = ReferenceISP(pattern, adc_bits)

    def block(self):
        return "isp", [self.logit]

    def unit(self) -> torch.Tensor:
        return torch.sigmoid(self.logit)

    def hyperparameters(self) -> dict[str, float]:
        return hp.from_unit(self.unit().detach().cpu().numpy())

    def train(self, mode: bool = True):
        super().train(mode)
        self.proxy.eval()  # the proxy is a fixed function: never in training mode
        return self

    def forward(self, raw: torch.Tensor, offset_px=None, full_field_px=None) -> torch.Tensor:
        """The proxy at the current hyperparameters (the crop's position is not used)."""
        return self.proxy(raw, self.unit())

    @torch.no_grad()
    def final(self, raw: torch.Tensor, offset_px=None, full_field_px=None) -> torch.Tensor:
        """The reference ISP (isp/reference.py, the "hardware" the proxy imitates) runs on the
        CPU: the RAW goes there and its output comes back, once per call."""
        return self.reference(raw.detach().cpu(), [self.hyperparameters()] * raw.shape[0]).to(raw)
