"""benches/lens_room.py's sharp lens shades exactly as the renderer does before it blurs
(optics/render.py ``_prepare``), at any crop offset."""

from __future__ import annotations

import torch

from optix_e2e.optics.render import _prepare


def test_the_sharp_lens_is_the_renderers_shading_without_its_psfs(load_bench):
    bench = load_bench("lens_room")
    g = torch.Generator().manual_seed(0)
    fields = torch.tensor([0.0, 0.4, 0.7, 1.0])
    vig = torch.tensor([[1.0, 1.0, 1.0], [0.95, 0.96, 0.94], [0.8, 0.82, 0.79], [0.6, 0.61, 0.58]])
    image = torch.rand(2, 3, 48, 64, generator=g)
    lens = bench.SharpShadedOptics(11, vig, fields, full_field_px=300.0)
    psfs = torch.ones(4, 3, 11, 11) / 121
    for offset in ((0.0, 0.0), (120.0, -80.0), (-200.0, 150.0)):
        want, _, _ = _prepare(image, psfs, fields, vig, 300.0, offset)
        assert torch.equal(lens(image, offset), want)
    # the shading is not a no-op here: the corner crop is darker than the centre's
    assert lens(image, (-200.0, 150.0)).sum() < lens(image, (0.0, 0.0)).sum()
