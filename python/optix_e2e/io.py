"""Files, written so that nothing is lost: atomic text, JSON and torch writes (fsync, then a
rename), the one rule for ``--out`` folders, small config files read with a limit, and the
strict JSON every command prints and writes (non-finite numbers become null).

A foundation module: it imports nothing from the package (docs/architecture.md).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from .errors import InputError


def fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def require_regular_file(path: "str | Path", what: str = "file") -> Path:
    """``path`` if it names a regular file: a pipe (FIFO), a device or a folder where a file is
    read would block for ever or read without end, so it is refused before it is opened, in one
    InputError naming the file. A missing file raises FileNotFoundError, as open() would."""
    import stat

    path = Path(path)
    if not stat.S_ISREG(path.stat().st_mode):
        raise InputError(f"{path}: the {what} is not a regular file")
    return path


def read_small_text(path: "str | Path", max_bytes: int = 1 << 20, what: str = "file") -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes``: a pipe, a device (/dev/zero)
    or a folder is refused before anything is read, so reading never blocks or runs without
    a limit. One ValueError naming the file; FileNotFoundError passes through."""
    path = require_regular_file(path, what)
    with open(path, "rb") as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputError(f"{path}: the {what} is larger than {max_bytes} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputError(f"{path}: the {what} is not UTF-8 text ({err.reason} at byte {err.start})") from None


def json_holds(path: Path, key: str) -> bool:
    """Whether the JSON object in ``path`` has ``key`` (True where there is no file): how a
    command tells its own result file from another command's of the same name (eval.json,
    tune.json) before it claims a folder. An unreadable file is not its own."""
    if not path.is_file():
        return True
    try:
        data = json.loads(read_small_text(path, 16 << 20, "result file"))
    except (ValueError, OSError):
        return False
    return isinstance(data, dict) and key in data


def claim_out_dir(
    out: "str | Path", kind: str, writes: "set[str] | frozenset[str]" = frozenset(), marker: str | None = None, own=None
) -> bool:
    """Check an ``--out`` folder before a command writes into it; True when it holds this
    kind of run already (its ``marker`` file: the command resumes or rewrites its own).

    Accepted: a folder that does not exist, is empty, holds ``marker``, or holds only names
    in ``writes`` (what this command writes: a previous run of it, or a start that stopped
    early) and passes ``own(folder)`` where given. Anything else holds files this command did
    not write, and is one ValueError naming the folder and a few of them: a command never
    writes into another kind of run or over a file it did not make."""
    out = Path(out)
    if not out.exists():
        return False
    if not out.is_dir():
        raise InputError(f"{out} is not a folder; choose another --out")
    if marker and (out / marker).is_file():
        return True
    names = sorted(p.name for p in out.iterdir())
    foreign = [n for n in names if n not in writes]
    if not foreign and (own is None or own(out)):
        return False
    shown = ", ".join(foreign[:3] or names[:3]) + (", ..." if len(foreign) > 3 else "")
    what = f"no {kind}" + (f" ({marker})" if marker else "")
    raise InputError(f"{out} is not empty and holds {what} but {shown}; choose another --out")


def write_text_atomic(path: Path, text: str) -> None:
    """Write UTF-8 ``text`` to a temporary file, fsync, rename over ``path``: the old file
    stays whole until the new one is; a failed write removes its temporary file."""
    path = Path(path)
    data = text.encode("utf-8")  # fails (UnicodeEncodeError) before any file is touched
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def write_json_atomic(path: Path, obj) -> None:
    """Write JSON to a temporary file, fsync, rename over ``path``. The text is made first, so
    an object JSON cannot hold (NaN, inf, a type it does not know) raises ValueError naming
    ``path`` and leaves nothing behind; a failed write removes its temporary file."""
    path = Path(path)
    try:
        text = json.dumps(obj, indent=2, allow_nan=False) + "\n"
    except (TypeError, ValueError) as err:
        raise InputError(f"{path}: cannot be written as JSON ({err})") from None
    write_text_atomic(path, text)


def save_atomic(obj, path: "str | Path") -> None:
    """``torch.save`` to memory first, then a temporary file, fsync, rename over ``path``: a
    checkpoint is whole or absent, never half written; a failed write removes its temporary."""
    from io import BytesIO  # the standard library's (absolute import)

    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = BytesIO()
    torch.save(obj, buf)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(buf.getvalue())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def to_jsonable(obj):
    """Numpy scalars/arrays -> Python; non-finite floats -> None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps(obj, **kw) -> str:
    """Strict JSON text of ``obj`` (numpy values converted, non-finite floats as null)."""
    return json.dumps(to_jsonable(obj), allow_nan=False, **kw)
