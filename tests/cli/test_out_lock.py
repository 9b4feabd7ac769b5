"""One command at a time writes into an --out folder (io.hold_out_dir): a second command started
into a folder another process is writing into is refused in one line naming the holder, before
it writes anything; once the holder ends, the folder is free again."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from optix_e2e.errors import InputError
from optix_e2e.io import claim_out_dir, hold_out_dir, release_out_dirs

HOLDER = textwrap.dedent(
    """
    import sys, time
    from optix_e2e.io import hold_out_dir
    hold_out_dir(sys.argv[1], "a test's holder")
    print("held", flush=True)
    sys.stdin.read()  # until the test closes our stdin
    """
)


@pytest.fixture
def held(tmp_path):
    """``tmp_path / "out"`` held by another process until the test ends."""
    out = tmp_path / "out"
    p = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert p.stdout.readline().strip() == "held"
    yield out, p
    if p.poll() is None:
        p.stdin.close()
        p.wait(timeout=60)


def test_a_folder_another_process_holds_is_refused_until_it_lets_go(held):
    out, p = held
    with pytest.raises(
        InputError, match=rf"out: another optix command is writing into it now \(pid {p.pid}: a test's holder\)"
    ):
        claim_out_dir(out, "design run", marker="config.json")
    assert not out.exists()  # nothing written
    hold_out_dir(out.parent, "its parent")  # another folder: free
    p.stdin.close()
    p.wait(timeout=60)
    claim_out_dir(out, "design run", marker="config.json")  # free now
    hold_out_dir(out, "again")  # held by this process already: nothing to do
    release_out_dirs()


def test_two_commands_into_one_folder_at_once_the_second_is_refused(held, optix, smoke_design):
    out, _ = held
    for args in (
        smoke_design("iq-software", out),
        ["dataset", "generate", "cooke-f50", "-n", "2", "--seed", "1", "--out", str(out)],
        ["demo", "--out", str(out)],
    ):
        r = optix(*args)
        assert r.returncode == 1, r.stdout + r.stderr
        assert "another optix command is writing into it now" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()
