"""Errors as one clear message: a Python plugin's exception that Mitsuba's loader wraps in a RuntimeError
whose text holds the plugin's traceback (nanobind's ``Traceback (most recent call last):``, the frames, then
``ValueError: ...``) loses the frames where it is a user's error (an invalid parameter: ``ValueError``,
``MemoryError``) and keeps them where it is not (a bug wants its traceback). Mitsuba's own messages lose
the C++ source locations (``[parser.cpp:1718]``, ``[properties.h:868]``), and its XML parser's "could not
parse" ones, which name a line and column only, get the element there: the property's name, what it held
and how to write it (``named_property``)."""

from __future__ import annotations

import pathlib
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


#: A C++ source location in Mitsuba's messages: ``[parser.cpp:1718] ``, ``[properties.h:868] ``.
SOURCE_LOCATION = re.compile(r"\[[\w.-]+\.(?:cpp|cc|cxx|c|h|hh|hpp|inl)(?::\d+)?\]\s*")
#: Mitsuba's XML parser on a value it cannot read: where (file, line, column) and what.
_UNPARSED = re.compile(r'(?P<where>(?:Error while loading|While loading|At) (?P<file>.+?) \(line (?P<line>\d+), '
                       r'col (?P<col>\d+)\)): (?P<what>could not parse (?:[\w ]+?) value "(?P<value>[^"]*)")')
_TAG = re.compile(r"<(?P<tag>[\w:.-]+)(?P<attrs>(?:\s+[\w:.-]+\s*=\s*(?:\"[^\"]*\"|'[^']*'))*)\s*/?>")
_ATTR = re.compile(r"([\w:.-]+)\s*=\s*(?:\"([^\"]*)\"|'([^']*)')")


def _element_at(path: pathlib.Path, line: int, col: int) -> tuple[str, dict] | None:
    """The XML element (tag, attributes) whose start tag opens at or before ``line``:``col`` of ``path`` (the
    position Mitsuba's parser reports), or None where the file or the tag cannot be read."""
    try:
        lines = path.read_text(errors="replace").splitlines(keepends=True)
    except OSError:
        return None
    if not 1 <= line <= len(lines):
        return None
    text = "".join(lines[:line - 1]) + lines[line - 1][:max(col, 1)]
    start = text.rfind("<")
    m = _TAG.match("".join(lines)[start:]) if start >= 0 else None
    if m is None:
        return None
    return m["tag"], {k: a if a else b for k, a, b in _ATTR.findall(m["attrs"])}


def how_to_write(tag: str, value: str) -> str:
    """How a value of an XML element ``tag`` is written, for a value Mitsuba could not parse."""
    try:
        number = float(value)
    except ValueError:
        number = None
    if tag == "integer":
        if re.fullmatch(r"[+-]?\d+", value.strip()):
            return "an <integer> holds -2^63 .. 2^63 - 1"
        if number is not None and number.is_integer() and abs(number) < 2**63:
            return f'an <integer> is written in digits: value="{int(number)}"'
        if number is not None:
            return "an <integer> takes a whole number (a <float> where the plugin takes a fraction)"
        return "an <integer> takes a whole number, written in digits"
    if tag == "float":
        comma = "; a decimal point, not a comma" if "," in value else ""
        return f"a <float> takes one number, such as 0.5 or 1e-3{comma}"
    if tag in ("rgb", "color"):
        return "an <rgb> takes three numbers (or one for grey), such as 0.5, 0.5, 0.5"
    return ""


def named_property(text: str) -> str:
    """Mitsuba's "could not parse ... value" message (line and column only) with the element there, which
    names the property and what it held (``$name`` when a scene parameter gave it) and how to write it:
    ``... (line 15, col 14): <integer name="count" value="1e6"/>: could not parse integer value "1e6"; an
    <integer> is written in digits: value="1000000"``. Other text is returned as it is."""
    m = _UNPARSED.search(text)
    found = m and _element_at(pathlib.Path(m["file"]), int(m["line"]), int(m["col"]))
    if not found:
        return text
    tag, attrs = found
    shown = " ".join(f'{k}="{attrs[k]}"' for k in ("name", "value") if k in attrs)
    how = how_to_write(tag, m["value"])
    named = f'{m["where"]}: <{tag} {shown}/>: {m["what"]}' + (f"; {how}" if how else "")
    return text[:m.start()] + named + text[m.end():]


__all__ = ["SOURCE_LOCATION", "USER_ERRORS", "how_to_write", "named_property", "without_traceback"]
