"""Seeded fuzzing of lens input files: mutate the bundled lenses' JSON and .zmx text (numbers
swapped for extreme values, lines dropped, repeated or swapped, truncation, stray bytes,
keywords changed), load each mutant as a user would and run paraxial analysis, a spot, an
FFT PSF and an RGB PSF on it. Every outcome must be a result without NaN or one of the
project's own errors; anything else is listed. Run as a script (tests/lens/test_fuzz.py runs it in
a child process, so that an abort of the process is seen as such):

    python tests/lens/fuzz_lens_inputs.py --n 400 --seed 0 --out fuzz.json
"""

from __future__ import annotations

import argparse
import json
import math
import random
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from optix_e2e import _engine
from optix_e2e.lens import Lens, bundled_lenses
from optix_e2e.lens.glass import GlassError
from optix_e2e.lens.prescription import PrescriptionError
from optix_e2e.lens.zemax.common import ZemaxError

# what a bad input may raise: the project's own error types (the file readers' and the
# engine's hierarchy); a plain ValueError, TypeError, ... is a bug
OURS = (PrescriptionError, ZemaxError, GlassError, _engine.EngineError)
EXTREMES = [
    "0",
    "-0",
    "1e300",
    "-1e300",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "1" + "0" * 400,
    "-7",
    "3.5",
    "1e7",
    "123456789",
    "0.0001",
    "-1e-9",
    "2147483648",
]
NUMBER = re.compile(r"(?<![A-Za-z_])-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def mutate(text: str, rng: random.Random) -> str:
    lines = text.splitlines(keepends=True)
    kind = rng.randrange(8)
    if kind <= 2:  # a number replaced (most productive: every parameter, count and index)
        spots = list(NUMBER.finditer(text))
        if spots:
            m = rng.choice(spots)
            return text[: m.start()] + rng.choice(EXTREMES) + text[m.end() :]
    if kind == 3 and len(lines) > 1:  # a line dropped
        del lines[rng.randrange(len(lines))]
        return "".join(lines)
    if kind == 4 and lines:  # a line repeated
        i = rng.randrange(len(lines))
        lines.insert(i, lines[i])
        return "".join(lines)
    if kind == 5 and len(lines) > 1:  # two lines swapped
        i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
        return "".join(lines)
    if kind == 6:  # truncated
        return text[: rng.randrange(len(text) + 1)]
    # stray characters or bytes inserted
    i = rng.randrange(len(text) + 1)
    return text[:i] + rng.choice(["\x00", "\u00e9", "}", "{", "[", '"', ",", " SURF 3\n", "\ufeff", "é"]) + text[i:]


def _finite(x) -> bool:
    """No NaN anywhere in a result (None stands for 'not reported')."""
    if isinstance(x, dict):
        return all(_finite(v) for v in x.values())
    if isinstance(x, (list, tuple)):
        return all(_finite(v) for v in x)
    if isinstance(x, np.ndarray):
        return not np.isnan(x).any() if x.dtype.kind == "f" else True
    if isinstance(x, float):
        return not math.isnan(x)
    return True


def exercise(path: Path) -> str:
    """Load and use a lens file; the stage reached ("ok") or the error's type name."""
    try:
        lens = Lens.load(path)
        results = [lens.paraxial()]
        f = min(lens.max_field_deg, 89.0)
        results.append(lens.spot(f, rings=6))
        results.append(lens.psf(f, None, "fft", pixel_um=1.0, size=32, pupil_samples=32))
        results.append(lens.psf_rgb(f * 0.5, method="fft", pixel_um=1.0, size=32, pupil_samples=32))
    except OURS as exc:
        return type(exc).__name__
    if not _finite(results):
        raise AssertionError(f"{path.name}: NaN in a result")
    return "ok"


def run(n: int, seed: int) -> dict:
    rng = random.Random(seed)
    sources = []
    for name in bundled_lenses():
        lens = Lens.load(name)
        sources.append((f"{name}.json", json.dumps(lens.data, indent=1)))
        sources.append((f"{name}.zmx", lens.to_zmx()))
    outcomes: dict[str, int] = {}
    bad = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            name, text = sources[i % len(sources)]
            mutant = text
            for _ in range(rng.choice([1, 1, 2, 3])):
                mutant = mutate(mutant, rng)
            path = Path(tmp) / f"m{i}_{name}"
            path.write_bytes(mutant.encode("utf-8", errors="surrogateescape"))
            try:
                what = exercise(path)
            except BaseException as exc:  # anything not ours: recorded with the mutant
                what = f"UNEXPECTED {type(exc).__name__}"
                bad.append(
                    {"i": i, "source": name, "error": f"{type(exc).__name__}: {exc}"[:400], "mutant": mutant[:4000]}
                )
            outcomes[what] = outcomes.get(what, 0) + 1
    return {"n": n, "seed": seed, "outcomes": outcomes, "unexpected": bad}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    rep = run(a.n, a.seed)
    text = json.dumps(rep, indent=1)
    if a.out:
        a.out.write_text(text)
    print(json.dumps({k: v for k, v in rep.items() if k != "unexpected"} | {"n_unexpected": len(rep["unexpected"])}))
    sys.exit(0)


if __name__ == "__main__":
    main()
