"""Text from outside (file contents, file names) made safe to show and to store.

A .zmx line or a file name can hold control bytes (an escape sequence would drive the
terminal that prints an error) or bytes that are not UTF-8 (they cannot go into JSON or the
engine's lens text). Both are written as backslash escapes here, once, for every message.
"""

from __future__ import annotations

import os
import unicodedata


def printable(text: str) -> str:
    """``text`` with control and other non-printing characters written as escapes (\\x1b,
    \\u202e); letters of every script and ordinary spaces are kept."""
    return "".join(
        c
        if c == " " or c.isprintable() or unicodedata.category(c)[0] not in "CZ"
        else c.encode("unicode_escape").decode("ascii")
        for c in text
    )


def display_name(path: "str | os.PathLike") -> str:
    """A file name as UTF-8 text: bytes the file system gave that are not UTF-8 as \\xNN,
    control characters escaped."""
    return printable(os.fsencode(path).decode("utf-8", "backslashreplace"))
