"""Reading the torch files we write (checkpoints, training states) without running code.

``torch.load(weights_only=True)`` unpickles only tensors, dicts, lists, tuples, strings and
numbers; a crafted file that asks for anything else (a class, ``exec``) is refused before
any of it runs. Every loader in the package goes through :func:`load_plain`.
"""

from __future__ import annotations

import pickle
import re
import stat
from pathlib import Path

from .errors import InputError

#: What restoring a damaged state raises once it is loaded as plain data: a missing or
#: misspelt key, a value of another type or shape, a count out of reason. Every resume
#: (design runs, surrogate and detector training) turns these into one error naming the file.
DAMAGED_STATE_ERRORS = (KeyError, TypeError, ValueError, RuntimeError, AttributeError, IndexError, OverflowError)


def _reason(exc: BaseException) -> str:
    """torch's long weights_only message cut to what went wrong."""
    text = " ".join(str(exc).split())
    found = re.search(r"Unsupported global: GLOBAL (\S+)", text)
    if found:
        return f"it asks for {found.group(1)}"
    found = re.search(r"WeightsUnpickler error: (.*?)(?: Check the documentation|$)", text)
    text = found.group(1) if found else text
    if len(text) > 160:  # cut at a word, and say so
        text = text[:160].rsplit(" ", 1)[0] + " ..."
    return text


def load_plain(path: "str | Path", what: str, error: type[Exception] = InputError, map_location="cpu"):
    """The contents of a torch file holding only plain data; anything else raises ``error``
    with one line naming the file and ``what`` it should have been."""
    import torch

    try:
        if Path(path).is_dir():
            raise IsADirectoryError(path)
        if not stat.S_ISREG(Path(path).stat().st_mode):  # a FIFO or a device would block torch.load
            raise error(f"{path}: the {what} is not a regular file")
        return torch.load(path, map_location=map_location, weights_only=True)
    except FileNotFoundError:
        raise error(f"{path}: no such {what}") from None
    except IsADirectoryError:
        raise error(f"{path}: is a directory, not a {what}") from None
    except error:
        raise  # the line above
    except pickle.UnpicklingError as exc:
        raise error(
            f"{path}: refused as a {what}: not plain data ({_reason(exc)}; only tensors, dicts, "
            f"lists, strings and numbers are loaded, so a file cannot run code)"
        ) from None
    except Exception as exc:  # torch raises many kinds for a damaged file
        raise error(f"{path}: unreadable {what} ({type(exc).__name__}: {_reason(exc)})") from None


def build_module(factory, config, state_dict, path, what: str, error: type[Exception] = InputError):
    """``factory(**config)`` with ``state_dict`` loaded, checked first: the config is a dict the
    factory accepts, the weights are finite tensors, and their names and shapes are the ones
    that config builds (tried on the meta device, so a hostile config allocates nothing)."""
    import torch

    if not isinstance(config, dict):
        raise error(f"{path}: damaged {what}: no config (found {type(config).__name__})")
    if not isinstance(state_dict, dict) or not state_dict:
        raise error(f"{path}: damaged {what}: no state_dict with the weights")
    odd = [str(k) for k, v in state_dict.items() if not (isinstance(k, str) and isinstance(v, torch.Tensor))]
    if odd:
        raise error(f"{path}: damaged {what}: state_dict entries that are not named tensors ({', '.join(odd[:3])})")
    nonfinite = [k for k, v in state_dict.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if nonfinite:
        more = f" and {len(nonfinite) - 1} more" if len(nonfinite) > 1 else ""
        raise error(f"{path}: damaged {what}: non-finite (NaN or infinite) weights in {nonfinite[0]}{more}")
    try:
        with torch.device("meta"):
            expected = {k: tuple(v.shape) for k, v in factory(**config).state_dict().items()}
    except Exception as exc:  # whatever the constructor says about a bad config
        raise error(
            f"{path}: damaged {what}: config {config} is not valid "
            f"({type(exc).__name__}: {' '.join(str(exc).split())[:160]})"
        ) from None
    missing = [k for k in expected if k not in state_dict]
    extra = [k for k in state_dict if k not in expected]
    shape = [k for k in expected if k in state_dict and tuple(state_dict[k].shape) != expected[k]]
    if missing or extra or shape:
        parts = [
            f"{label} {', '.join(keys[:3])}" + (f" (+{len(keys) - 3})" if len(keys) > 3 else "")
            for label, keys in (("missing", missing), ("unexpected", extra), ("wrong shape", shape))
            if keys
        ]
        raise error(f"{path}: damaged {what}: weights do not match its config ({'; '.join(parts)})")
    model = factory(**config)
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state_dict.items()})
    return model
