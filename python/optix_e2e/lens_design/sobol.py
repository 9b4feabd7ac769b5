"""Scrambled Sobol' points without importing scipy.stats.

``scipy.stats.qmc.Sobol`` costs 1.5 s of imports on the 2-core CPU (scipy.stats loads every
distribution), 15 % of ``optix dataset paper-triplet -n 600``. The sequence itself is a few
XORs, so the sampler draws it here with numpy: the same bits as
``qmc.Sobol(d, scramble=True, rng=np.random.default_rng(seed))`` of scipy 1.17 (tested
against it in tests/lens_design/test_sobol.py), which also keeps a seed's designs the same
when scipy changes its sampler.

The construction (Joe & Kuo 2008 direction numbers, the D(6) set that scipy ships as
``scipy/stats/_sobol_direction_numbers.npz``, read as data):

* direction numbers v[d, j] (30 bits) from each dimension's primitive polynomial by
  Bratley & Fox's recurrence;
* scrambling: a random lower-triangular binary matrix (unit diagonal) multiplies each
  direction number's bits (Matousek's linear matrix scramble), and a random digital shift
  starts the sequence;
* point i is the shift XOR the direction numbers picked by the bits of i's Gray code.

The random bits come from one child of the seed's generator (``SeedSequence.spawn``), in
scipy's order: the shift's (d, 30) bits, then the (d, 30, 30) matrices.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from ..errors import InputError

BITS = 30
_SCALE = 2.0**-BITS


def _direction_table() -> tuple[np.ndarray, np.ndarray]:
    """(poly, vinit) of the direction numbers file scipy ships (no scipy module imported)."""
    spec = importlib.util.find_spec("scipy")
    if spec is None or not spec.submodule_search_locations:
        raise InputError("the Sobol' sampler needs scipy's direction numbers: scipy is not installed")
    path = Path(next(iter(spec.submodule_search_locations))) / "stats" / "_sobol_direction_numbers.npz"
    try:
        with np.load(path, allow_pickle=False) as f:
            return f["poly"].astype(np.int64), f["vinit"].astype(np.int64)
    except (OSError, KeyError, ValueError) as err:
        raise InputError(f"{path}: cannot read the Sobol' direction numbers ({err})") from None


def direction_numbers(d: int) -> np.ndarray:
    """(d, BITS) unscrambled direction numbers, column j scaled by 2^(BITS-1-j)."""
    poly, vinit = _direction_table()
    if d > len(poly):
        raise InputError(f"the Sobol' sampler has direction numbers for {len(poly)} dimensions, asked for {d}")
    v = np.zeros((d, BITS), np.int64)
    v[0] = 1
    for k in range(1, d):
        p = int(poly[k])
        m = p.bit_length() - 1  # the polynomial's degree
        row = [int(x) for x in vinit[k, :m]]
        for j in range(m, BITS):  # Bratley & Fox (1988), section 2
            new = row[j - m]
            for i in range(m):
                if (p >> (m - 1 - i)) & 1:
                    new ^= row[j - i - 1] << (i + 1)
            row.append(new)
        v[k] = row
    return v << (BITS - 1 - np.arange(BITS))


def _bits(x: np.ndarray) -> np.ndarray:
    """(..., BITS) binary digits of x, least significant first."""
    return (x[..., None] >> np.arange(BITS)) & 1


class ScrambledSobol:
    """The scrambled Sobol' sequence in [0, 1)^d of a seed; ``random(n)`` gives the next n
    points (n, d), ``num_generated`` counts those given."""

    def __init__(self, d: int, seed: int):
        if d < 1:
            raise InputError(f"the Sobol' sampler needs at least one dimension, got {d}")
        parent = np.random.default_rng(seed).bit_generator
        rng = np.random.Generator(type(parent)(parent.seed_seq.spawn(1)[0]))
        shift_bits = rng.integers(0, 2, size=(d, BITS), dtype=np.uint32).astype(np.int64)
        ltm = np.tril(rng.integers(0, 2, size=(d, BITS, BITS), dtype=np.uint32).astype(np.int64))
        ltm[:, np.arange(BITS), np.arange(BITS)] = 1
        v = direction_numbers(d)
        # bit (BITS-1-p) of a scrambled number = parity of row p of the matrix (its entry i
        # weighs bit BITS-1-i) against the number's bits
        rows = ltm[:, :, ::-1]  # rows[d, p, k] multiplies bit k
        parity = np.einsum("dpk,djk->djp", rows, _bits(v)) & 1
        self._v = (parity << (BITS - 1 - np.arange(BITS))).sum(axis=2)  # (d, BITS)
        self._shift = (shift_bits << np.arange(BITS)).sum(axis=1)
        self.d = d
        self.num_generated = 0

    def random(self, n: int) -> np.ndarray:
        i = np.arange(self.num_generated, self.num_generated + n, dtype=np.int64)
        gray = i ^ (i >> 1)
        q = np.broadcast_to(self._shift, (n, self.d)).copy()
        for b in range(BITS):
            on = ((gray >> b) & 1).astype(bool)
            if on.any():
                q[on] ^= self._v[:, b]
        self.num_generated += n
        return q * _SCALE
