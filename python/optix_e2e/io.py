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


#: the ``--out`` folders this process holds (hold_out_dir): real path -> the lock file's descriptor
_HELD: dict[str, int] = {}


def _lock_file(real: str) -> Path:
    """The lock file of the folder at ``real`` (its resolved path): in the machine's temporary
    folder, not in the folder itself, so a folder not made yet can be held and no file is added
    to what a run folder holds."""
    import hashlib
    import tempfile

    folder = Path(tempfile.gettempdir()) / f"optix-locks-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    return folder / (hashlib.sha256(real.encode()).hexdigest()[:32] + ".lock")


def hold_out_dir(out: "str | Path", kind: str) -> None:
    """Hold the ``--out`` folder ``out`` until this command ends (release_out_dirs): a second
    command writing into the same folder at the same time (another process) is refused in one
    line naming the holder, before it writes anything. An advisory lock (flock) on a file named
    after the folder's resolved path; it ends with the process however that ends. Held already
    by this process: nothing to do."""
    import fcntl

    if os.environ.get("RANK", "0") != "0":  # a torchrun command's ranks are one command: rank 0 holds
        return
    real = os.path.realpath(out)
    if real in _HELD:
        return
    fd = os.open(_lock_file(real), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "another process"
        os.close(fd)
        raise InputError(
            f"{out}: another optix command is writing into it now ({holder}); wait for it to end, or choose another --out"
        ) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()}: {kind}".encode(), 0)
    _HELD[real] = fd


def release_out_dirs() -> None:
    """Let go of every folder this process holds (the end of a command)."""
    for fd in _HELD.values():
        os.close(fd)
    _HELD.clear()


def claim_out_dir(
    out: "str | Path", kind: str, writes: "set[str] | frozenset[str]" = frozenset(), marker: str | None = None, own=None
) -> bool:
    """Check an ``--out`` folder before a command writes into it; True when it holds this
    kind of run already (its ``marker`` file: the command resumes or rewrites its own).

    Accepted: a folder that does not exist, is empty, holds ``marker``, or holds only names
    in ``writes`` (what this command writes: a previous run of it, or a start that stopped
    early) and passes ``own(folder)`` where given. Anything else holds files this command did
    not write, and is one ValueError naming the folder and a few of them: a command never
    writes into another kind of run or over a file it did not make. The folder is held for the
    rest of the command (hold_out_dir): one command at a time writes into it."""
    out = Path(out)
    hold_out_dir(out, kind)
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


def write_bytes_atomic(path: "str | Path", data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, fsync, rename over ``path``: the old
    file stays whole until the new one is; a failed write (a full disk, a read-only folder)
    removes its temporary file and raises OSError."""
    path = Path(path)
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


def write_text_atomic(path: "str | Path", text: str, encoding: str = "utf-8") -> None:
    """``text`` written atomically (write_bytes_atomic), as UTF-8 unless ``encoding`` says
    otherwise; a text the encoding cannot hold fails before any file is touched."""
    write_bytes_atomic(path, text.encode(encoding))


def write_json_atomic(path: "str | Path", obj) -> None:
    """Write JSON to a temporary file, fsync, rename over ``path``. The text is made first, so
    an object JSON cannot hold (NaN, inf, a type it does not know) raises ValueError naming
    ``path`` and leaves nothing behind; a failed write removes its temporary file."""
    path = Path(path)
    try:
        text = json.dumps(obj, indent=2, allow_nan=False) + "\n"
    except (TypeError, ValueError) as err:
        raise InputError(f"{path}: cannot be written as JSON ({err})") from None
    write_text_atomic(path, text)


def write_record_atomic(path: "str | Path", obj, indent: int = 2) -> None:
    """A record (a summary, a report) as strict JSON (``dumps``: numpy values converted, a
    non-finite number written as null, not as JSON's invalid NaN), atomically."""
    write_text_atomic(path, dumps(obj, indent=indent) + "\n")


def write_csv_atomic(path: "str | Path", rows, header=None) -> None:
    """Rows (sequences) as CSV (the csv module's dialect: commas, CRLF line ends), atomically."""
    import csv
    from io import StringIO  # the standard library's (absolute import)

    buf = StringIO()
    w = csv.writer(buf)
    if header is not None:
        w.writerow(header)
    w.writerows(rows)
    write_text_atomic(path, buf.getvalue())


def open_log(path: "str | Path"):
    """A file a run appends rows to as it goes (history.csv), opened for appending: the one
    write that is not atomic, so each row is whole once flushed and a resume drops the rows
    after its checkpoint (tasks/detector_train.py)."""
    return open(path, "a", newline="", encoding="utf-8")


def save_npy_atomic(path: "str | Path", array) -> None:
    """A numpy array as .npy, atomically."""
    from io import BytesIO  # the standard library's (absolute import)

    buf = BytesIO()
    np.save(buf, array)
    write_bytes_atomic(path, buf.getvalue())


def save_figure(fig, path: "str | Path", **kw) -> None:
    """A matplotlib figure saved atomically (its format from ``path``'s suffix; ``kw`` to
    savefig: dpi, ...)."""
    from io import BytesIO  # the standard library's (absolute import)

    path = Path(path)
    buf = BytesIO()
    fig.savefig(buf, format=path.suffix.lstrip(".") or "png", **kw)
    write_bytes_atomic(path, buf.getvalue())


def save_image(path: "str | Path", image) -> None:
    """An 8-bit image (H x W x 3 uint8) as the file type its suffix names, atomically."""
    from io import BytesIO  # the standard library's (absolute import)

    import imageio.v3 as iio

    path = Path(path)
    buf = BytesIO()
    iio.imwrite(buf, image, extension=path.suffix)
    write_bytes_atomic(path, buf.getvalue())


def _quiet_tensorboard_thread(args) -> None:
    """threading.excepthook: TensorBoard's writer thread failing to write (a full disk, a
    read-only folder) prints no traceback; the same OSError reaches the run at its next write
    or at close, where the command reports it in one line."""
    if isinstance(args.exc_value, OSError) and type(args.thread).__name__ == "_AsyncWriterThread":
        return
    _THREAD_HOOK(args)


_THREAD_HOOK = None


def tensorboard_writer(folder: "str | Path"):
    """A TensorBoard SummaryWriter into ``folder`` (``tb/`` of a run), whose background writer's
    errors come back to the run as one OSError instead of a thread's traceback."""
    import threading

    from torch.utils.tensorboard import SummaryWriter

    global _THREAD_HOOK
    if _THREAD_HOOK is None:
        _THREAD_HOOK = threading.excepthook
        threading.excepthook = _quiet_tensorboard_thread
    return SummaryWriter(str(folder))


def save_atomic(obj, path: "str | Path") -> None:
    """``torch.save`` to memory first, then a temporary file, fsync, rename over ``path``: a
    checkpoint is whole or absent, never half written; a failed write removes its temporary."""
    from io import BytesIO  # the standard library's (absolute import)

    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = BytesIO()
    torch.save(obj, buf)
    write_bytes_atomic(path, buf.getvalue())


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
