"""Run an ``optix`` command (``python tests/camera_design/ddp_spy.py ARGS...``, e.g. under torchrun) with an
audit hook that records every file or directory this process creates, opens for writing,
renames or removes under $OPTIX_SPY_OUT, and write the list to
$OPTIX_SPY_DIR/rank<RANK>.json at the end: tests/camera_design/test_distributed_training.py checks that
rank 0 alone writes."""

from __future__ import annotations

import json
import os
import sys

OUT = os.path.realpath(os.environ["OPTIX_SPY_OUT"])
WRITES = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC
seen: list[str] = []


def _record(event: str, path) -> None:
    if isinstance(path, int) or path is None:
        return
    p = os.path.realpath(os.fsdecode(path))
    if p == OUT or p.startswith(OUT + os.sep):
        seen.append(f"{event} {os.path.relpath(p, OUT)}")


def _hook(event: str, args) -> None:
    if event == "open":
        path, mode, flags = args
        if (isinstance(mode, str) and any(c in mode for c in "wax+")) or (isinstance(flags, int) and flags & WRITES):
            _record(event, path)
    elif event == "os.rename":
        _record(event, args[0])
        _record(event, args[1])
    elif event in ("os.mkdir", "os.remove", "os.rmdir", "shutil.rmtree", "shutil.copyfile"):
        _record(event, args[0] if event != "shutil.copyfile" else args[1])


sys.addaudithook(_hook)
code = 0
try:
    from optix_e2e.cli import main

    main(sys.argv[1:], prog_name="optix")
except SystemExit as exc:
    code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
finally:
    with open(os.path.join(os.environ["OPTIX_SPY_DIR"], f"rank{os.environ.get('RANK', '0')}.json"), "w") as f:
        json.dump(seen, f)
sys.exit(code)
