"""Errors as one clear message: a Python plugin's exception that Mitsuba's loader wraps in a RuntimeError
whose text holds the plugin's traceback (nanobind's ``Traceback (most recent call last):``, the frames, then
``ValueError: ...``) loses the frames where it is a user's error (an invalid parameter: ``ValueError``,
``MemoryError``) and keeps them where it is not (a bug wants its traceback)."""

from __future__ import annotations

import re

#: Exceptions whose traceback a user has no use for: what the plugins raise for a bad input.
USER_ERRORS = ("ValueError", "MemoryError", "MotesError")

_TRACEBACK = "Traceback (most recent call last):"
_FRAME = re.compile(r'^\s+File "[^"]*", line \d+')


def without_traceback(text: str) -> str | None:
    """``text`` less the Python traceback's frames (the exception's type and its message kept, all its lines),
    or None where it holds no traceback or one of another exception than ``USER_ERRORS``."""
    head, sep, tail = text.partition(_TRACEBACK)
    if not sep:
        return None
    lines = tail.strip("\n").splitlines()
    i = 0
    while i < len(lines) and (_FRAME.match(lines[i]) or (i > 0 and lines[i].startswith("    "))):
        i += 1
    kind, colon, message = "\n".join(lines[i:]).partition(": ")
    if not colon or kind.strip().rsplit(".", 1)[-1] not in USER_ERRORS:
        return None
    what = f"{kind.strip()}: {message.strip()}"
    return f"{head.rstrip()} {what}" if head.strip() else what


__all__ = ["USER_ERRORS", "without_traceback"]
