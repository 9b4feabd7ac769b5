"""The sampler's Sobol' sequence: scipy's bits without scipy.stats's import."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

from optix_e2e.errors import InputError
from optix_e2e.lens_design.sobol import ScrambledSobol, direction_numbers


@pytest.mark.parametrize("d", [1, 2, 12, 19, 40])
@pytest.mark.parametrize("seed", [0, 5])
def test_same_bits_as_scipy(d, seed):
    """Point for point equal to qmc.Sobol(scramble=True) over blocks drawn in the sampler's
    order (a power of two first, then doubling) and an odd block after them."""
    from scipy.stats import qmc

    ref = qmc.Sobol(d, scramble=True, seed=np.random.default_rng(seed))
    ours = ScrambledSobol(d, seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy's balance warning on the odd block
        for n in (1024, 1024, 2048, 5):
            assert np.array_equal(ours.random(n), ref.random(n))
    assert ours.num_generated == 4101


def test_unscrambled_numbers_are_sobols():
    """Unscrambled, the first dimensions give Sobol's textbook points: dimension 0 the van
    der Corput sequence in base 2, dimension 1 (polynomial x + 1) 1/2, 1/4, 3/4 for points 1-3."""
    v = direction_numbers(2).astype(float) * 2.0**-30
    assert np.array_equal(v[0, :4], [0.5, 0.25, 0.125, 0.0625])
    # point 3: Gray code 0b10 -> second direction number; point 2: 0b11 -> both
    assert v[1, 0] == 0.5 and v[1, 1] == 0.75
    assert float(int(v[1, 0] * 2**30) ^ int(v[1, 1] * 2**30)) * 2.0**-30 == 0.25


def test_balance():
    """A scrambled Sobol' block of 2^k points holds exactly one point in each of 2^k equal
    slabs of every axis (a (0, k, 1)-net per dimension)."""
    x = ScrambledSobol(6, 3).random(256)
    for j in range(6):
        assert np.array_equal(np.bincount((x[:, j] * 256).astype(int), minlength=256), np.ones(256))


def test_refuses_no_dimension():
    with pytest.raises(InputError, match="at least one dimension"):
        ScrambledSobol(0, 0)


def test_sampler_does_not_import_scipy_stats():
    """The dataset's sampler draws Sobol' points without loading scipy.stats (1.5 s)."""
    code = (
        "import sys\n"
        "from optix_e2e.lens_design.sampling import _unit_block\n"
        "_unit_block('sobol', 3, 8, 0, {})\n"
        "print('scipy.stats' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
