"""A probe of every command's numeric options with hostile values (seeded, bounded).

For every command of ``optix`` and every integer or float option, the probe passes a value a
careless or hostile user might type (nan, inf, huge, negative, not a number), first on the
command line so click checks it before anything else, in a folder holding a file the command
must not touch. It asserts what the issue "bad input" asks of every command: exit status 2
(a usage error), one ``Error:`` line that names the option, no traceback, nothing written and
every pre-existing file byte-identical. tests/cli/test_bad_input.py holds the probes that need a
run to exist first (damaged states, diverging training, other runs' folders).
"""

from __future__ import annotations

import random

import click
import pytest
from click.testing import CliRunner

from optix_e2e.cli import main

HOSTILE_INT = ["nan", "inf", "-1", "9223372036854775807", "99999999999999999999999", "1e3", "abc", ""]
HOSTILE_FLOAT = ["nan", "inf", "-inf", "1e999", "abc", "", "0x1p2000"]


def _options():
    def walk(cmd, path):
        if isinstance(cmd, click.Group):
            for name, sub in sorted(cmd.commands.items()):
                yield from walk(sub, [*path, name])
        else:
            for p in cmd.params:
                if isinstance(p, click.Option) and isinstance(
                    p.type, (click.types.IntParamType, click.types.FloatParamType)
                ):
                    yield path, p, any("--out" in q.opts for q in cmd.params)

    yield from walk(main, [])


def _cases(seed: int = 0, per_option: int = 2):
    rng = random.Random(seed)
    for path, opt, _ in _options():
        pool = HOSTILE_INT if isinstance(opt.type, click.types.IntParamType) else HOSTILE_FLOAT
        pool = [v for v in pool if _rejects(opt, v)]  # -1 is a valid signed offset, 1e3 a valid float
        for value in rng.sample(pool, min(per_option, len(pool))):
            yield pytest.param(path, opt.opts[0], value, id=f"{' '.join(path)} {opt.opts[0]}={value!r}")


def _rejects(opt, value: str) -> bool:
    """Whether ``value`` is out of ``opt``'s domain (some hostile values are fine for some options:
    -1 for a signed float, 1e3 for a float)."""
    try:
        v = opt.type.convert(value, None, None)
    except click.BadParameter:
        return True
    return v is None


@pytest.mark.parametrize("path, option, value", list(_cases()))
def test_a_hostile_numeric_option_is_one_usage_error_and_touches_nothing(tmp_path, path, option, value):
    opt, has_out = next((p, o) for pp, p, o in _options() if pp == path and p.opts[0] == option)
    assert _rejects(opt, value)
    keep = tmp_path / "keep.txt"
    keep.write_bytes(b"a file no command may touch\n")
    out = tmp_path / "out"
    args = [*path, option, value] + (["--out", str(out)] if has_out else [])
    res = CliRunner().invoke(main, args, catch_exceptions=True)
    assert res.exit_code == 2, (res.exit_code, res.output, res.exception)
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    errors = [ln for ln in res.output.splitlines() if ln.startswith("Error:")]
    assert len(errors) == 1 and option in errors[0], res.output
    assert keep.read_bytes() == b"a file no command may touch\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]  # nothing written, --out not made


@pytest.mark.slow
def test_whole_commands_under_a_time_bound_exit_with_one_line(tmp_path):
    # as a user runs them (a real process, so a hang, a crash or a traceback would show):
    # a pipe as a config file used to block forever, a huge thread count to segfault
    import os
    import subprocess
    import sys

    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    probes = [
        (["design", "iq-software", "--config", str(fifo), "--out", str(tmp_path / "a")], 1, "not a regular file"),
        (["design", "iq-software", "--threads", "50000", "--out", str(tmp_path / "b")], 2, "--threads"),
        (["scenes", "street", "--out", str(tmp_path / "c"), "-n", "1", "--size", "100000x100000"], 2, "--size"),
    ]
    for args, code, words in probes:
        res = subprocess.run([sys.executable, "-m", "optix_e2e", *args], capture_output=True, text=True, timeout=120)
        assert res.returncode == code, (args, res.returncode, res.stderr[-2000:])
        lines = [ln for ln in res.stderr.splitlines() if ln.startswith("Error:")]
        assert len(lines) == 1 and words in lines[0] and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe.toml"]  # no --out folder claimed
