"""The Poisson quantile of the common-random-number shot noise (sensor/poisson.py)."""

import numpy as np
import pytest
import torch
from scipy.stats import poisson

from optix_e2e.errors import InputError
from optix_e2e.sensor.emva import raw_from_electrons
from optix_e2e.sensor.poisson import poisson_quantile


@pytest.mark.parametrize("hi", [5.0, 200.0, 40_000.0])
def test_the_quantile_is_scipys(hi):
    """Against scipy.stats.poisson.ppf (boost's inverse, an independent method) on 400,000
    uniforms and rates up to a full well (and zero rates): every value equal. Measured equal on
    12 million draws over the same ranges."""
    g = torch.Generator().manual_seed(int(hi))
    n = 400_000
    lam = torch.rand(n, generator=g, dtype=torch.float64) * hi
    lam[:500] = 0.0
    u = torch.rand(n, generator=g, dtype=torch.float64)
    ours = poisson_quantile(u, lam)
    assert ours.dtype == torch.float64 and ours.shape == (n,)
    np.testing.assert_array_equal(ours.numpy(), poisson.ppf(u.numpy(), lam.numpy()))


def test_the_quantile_by_definition_at_the_edges():
    """The smallest k with P(K <= k) >= u, where the guess is far: u near 0 and 1 at small and
    large rates (u = 1e-200 at 10^4: thousands of steps from the guess, the bisection's case),
    rate 0 (always 0), u = 0 (0; scipy says -1), negative rates as 0."""
    u = torch.tensor([1e-300, 1e-12, 0.5, 1 - 2**-53, 1 - 2**-53, 0.3, 0.0, 0.9, 1e-200], dtype=torch.float64)
    lam = torch.tensor([3.0, 1e4, 1e-6, 0.01, 3e4, 0.0, 7.0, -2.0, 1e4], dtype=torch.float64)
    k = poisson_quantile(u, lam)
    for kk, uu, ll in zip(k.tolist(), u.tolist(), lam.clamp_min(0).tolist()):
        assert kk == int(kk) and kk >= 0
        assert poisson.cdf(kk, ll) >= uu
        assert kk == 0 or poisson.cdf(kk - 1, ll) < uu
    assert k[5] == 0 and k[6] == 0 and k[7] == 0
    assert 5000 < k[8] < 8000


def test_refuses_u_outside_the_unit_interval():
    for u in (1.0, -0.1, float("nan")):
        with pytest.raises(InputError, match="u in"):
            poisson_quantile(torch.tensor([u]), torch.tensor([1.0]))


def test_common_noise_draws_are_those_of_scipys_quantile():
    """The sensor's common-random-number path: the same DN as the former formula (scipy's
    quantile of the same three fields drawn in the same order)."""
    mu = torch.rand(1, 1, 64, 64, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 3000
    y = raw_from_electrons(mu, "imx249", generator=torch.Generator().manual_seed(9), common_noise=True)
    from optix_e2e.sensor.emva import dark_current_mean, get_preset

    p = get_preset("imx249")
    g = torch.Generator().manual_seed(9)
    u, z, q = (f(mu.shape, generator=g, dtype=torch.float64) for f in (torch.rand, torch.randn, torch.rand))
    lam = (mu + dark_current_mean(p)).clamp_min(0).numpy()
    e = torch.from_numpy(poisson.ppf(u.numpy(), lam)) + p.dark_noise_e * z
    want = (p.black_level_dn + p.gain_dn_per_e * torch.clamp(e, max=p.full_well_e) + q - 0.5).clamp(0, p.adc_max_dn)
    assert torch.equal(y, want)
