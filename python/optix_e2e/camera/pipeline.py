"""The composable camera of paper Eqs. 10-12: scene radiance -> optics -> sensor -> ISP.

    O = f_ISP( f_SENSOR( f_OPTIC(I, P_OPTIC) ), P_ISP )                     (Eqs. 10-11)

A scene crop is a window of the sensor frame: the caller says where its centre lies
(``offset_px`` from the optical axis) so its pixels see the PSFs of their own field. The crop
is rendered with a margin (the PSF half-width) and cut back before the sensor, so the light
that reaches its border from just outside is modelled.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
from torch import nn

from ..errors import InputError
from .stages import SensorStage


class Camera(nn.Module):
    """optics (FixedOptics or DifferentiableOptics) -> SensorStage -> ISP stage.

    forward(radiance [B, 3, H + 2m, W + 2m] linear, offset_px, generator) -> (sRGB [B, 3, H, W],
    RAW [B, 1, H, W]) with m = :attr:`margin`; the ISP in the loop (the proxy for a hardware
    ISP). ``final=True`` gives what the camera really outputs (the reference ISP for a
    hardware ISP; not differentiable)."""

    def __init__(self, optics: nn.Module, sensor: SensorStage, isp: nn.Module):
        super().__init__()
        self.optics, self.sensor, self.isp = optics, sensor, isp

    @property
    def margin(self) -> int:
        return int(self.optics.psf_size) // 2

    @property
    def device(self) -> torch.device:
        """Where the camera's tensors live (``camera.to(device)``): a batch goes there once."""
        return next(t.device for t in (*self.parameters(), *self.buffers()))

    def blocks(self) -> "OrderedDict[str, list[nn.Parameter]]":
        """The parameter blocks of the stages that have one, in pipeline order."""
        out: OrderedDict[str, list[nn.Parameter]] = OrderedDict()
        for stage in (self.optics, self.sensor, self.isp):
            b = stage.block() if hasattr(stage, "block") else None
            if b is None and hasattr(stage, "u"):  # DifferentiableOptics
                b = ("optics", [stage.u])
            if b is not None:
                out[b[0]] = b[1]
        return out

    def forward(
        self,
        radiance: torch.Tensor,
        offset_px=(0.0, 0.0),
        generator: torch.Generator | None = None,
        *,
        final: bool = False,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``final``: the camera's real output (evaluation): the reference ISP for a hardware
        ISP, and the sensor's common-random-number noise (the same draws for any camera given
        the same generator state)."""
        raw = self._raw(radiance, offset_px, generator, final)
        where = self._where(offset_px)
        out = self.isp.final(raw, *where) if final else self.isp(raw, *where)
        return out, raw

    @torch.no_grad()
    def final_batch(self, radiance: torch.Tensor, offsets_px, generators) -> torch.Tensor:
        """``forward(final=True)``'s sRGB [B, 3, H, W] for B samples at their own crop positions
        (``offsets_px``: B pairs) with their own noise generators (B): the optics and the
        sensor's common random numbers one sample at a time (each its own PSFs and draws, as
        alone), the ISP on the whole batch (its work, the larger part, in one call)."""
        if not (len(radiance) == len(offsets_px) == len(generators)):
            raise InputError(
                f"final_batch: one offset and one generator per sample, got {len(radiance)} samples, "
                f"{len(offsets_px)} offsets, {len(generators)} generators"
            )
        raw = torch.cat([self._raw(x, o, g, True) for x, o, g in zip(radiance.split(1), offsets_px, generators)])
        offsets = torch.tensor([[float(a), float(b)] for a, b in offsets_px], device=raw.device)
        return self.isp.final(raw, *self._where(offsets))

    def _raw(self, radiance: torch.Tensor, offset_px, generator, common_noise: bool) -> torch.Tensor:
        """The optics at the crop's position, the margin cut, then the sensor's RAW."""
        m = self.margin
        image = self.optics(radiance, offset_px)
        if m:
            image = image[..., m:-m, m:-m]
        # the photon count follows the lens's f-number where the optics carry one (Eq. 3)
        f_number = self.optics.f_number() if hasattr(self.optics, "f_number") else None
        return self.sensor(image, generator, common_noise=common_noise, f_number=f_number)

    def _where(self, offset_px) -> tuple:
        """What the ISP is told of where the crop lies in the frame (a software ISP that sees
        the field position undoes a blur and a shading that vary over it): one offset, or one
        per sample [B, 2]."""
        if not getattr(self.isp, "takes_position", False):
            return ()
        return (offset_px, getattr(self.optics, "full_field_px", None))
