"""Particle sets on disk: positions (scene units), radii (micrometres) and species indices.

================  ==========================================================================================
``.npz``          arrays ``positions`` (n, 3), ``radii_um`` (n,), optional ``species`` (n,) ints; other
                  arrays are ignored
``.npy``          one (n, 4) or (n, 5) array: x, y, z, radius_um[, species]
``.csv``          UTF-8 text (a byte-order mark is ignored): a header line naming the columns
                  ``x,y,z,radius_um`` (``species`` optional, any order, no other names), then one particle per
                  line; every line, the last included, ends with a line break
``.ply``          a point cloud, ASCII or binary (``meshio`` writes them): vertex ``x y z`` plus ``radius``
                  (micrometres) or Houdini's ``pscale`` (scene units, converted with ``scale_m``), optional
                  ``species``; other scalar vertex properties and other elements are skipped
================  ==========================================================================================

``load_particles(path, scale_m=1.0, n_species=None)`` validates everything and raises ``ParticleFileError`` (a
``ValueError``) naming the file and the element (particle index or file line) and field: a path that is not a
regular file (missing, unreadable, a directory, a FIFO — checked before and after opening, so nothing blocks),
non-finite coordinates, radii below MIN_RADIUS_UM (1e-9 um), unknown species, empty sets, and files whose body
disagrees with their header (a PLY's element counts and property types, a .npy array's shape, too few or extra
rows or bytes, checked before anything of the declared size is allocated). Pickled data is never loaded. Nothing else
escapes from a bad file; ``docs/python-api.md`` ("Particle files") lists the rules. PLY and .npy are read here
rather than by meshio and ``numpy.load``, which take a header's counts and shapes on trust (a short file read
short; a huge count allocated before the read failed); numpy still parses the headers and the rows.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import pathlib
import re
import stat
import warnings
import zipfile
from dataclasses import dataclass, field

import numpy as np


@dataclass
class ParticleSet:
    positions: np.ndarray  # (n, 3) scene units
    radii_um: np.ndarray  # (n,)
    species: np.ndarray  # (n,) integers (their type as read; int64 for non-integer input)

    def __len__(self) -> int:
        return int(self.positions.shape[0])


class ParticleFileError(ValueError):
    """A particle file that cannot be used; the message names the file and the element or field."""


#: Particles checked per step (bounds the validation's temporaries to a few MB).
_CHUNK = 1 << 20
#: The smallest radius a particle file may give (micrometres; 1e-15 m, a nucleus): smaller ones are not particles,
#: and their cross sections underflow on the way to scene units.
MIN_RADIUS_UM = 1e-9


def _fail(path, message: str):
    raise ParticleFileError(f"{path}: {message}")


def _validate(path, pos, radii, species, n_species) -> ParticleSet:
    pos, radii = _real(path, "positions", pos), _real(path, "radii", radii)
    pos = np.asarray(pos, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64).ravel()
    if pos.ndim != 2 or pos.shape[1] != 3:
        _fail(path, f"positions must have shape (n, 3), got {pos.shape}")
    n = pos.shape[0]
    if n == 0:
        _fail(path, "the particle set is empty")
    if radii.size != n:
        _fail(path, f"{radii.size} radii for {n} particles")
    # Checked in chunks, so that 1e8 particles cost no full-size temporaries (masks, float copies).
    species = np.zeros(n, dtype=np.uint32) if species is None else _real(path, "species", species).ravel()
    if species.size != n:
        _fail(path, f"{species.size} species entries for {n} particles")
    limit = n_species if n_species is not None else np.inf
    for a in range(0, n, _CHUNK):
        sl = slice(a, min(a + _CHUNK, n))
        bad = ~np.isfinite(pos[sl])
        if bad.any():
            i, k = map(int, np.argwhere(bad)[0])
            _fail(path, f"particle {a + i}: field {'xyz'[k]} is {pos[a + i, k]} (must be finite)")
        bad = ~(np.isfinite(radii[sl]) & (radii[sl] >= MIN_RADIUS_UM))
        if bad.any():
            i = a + int(np.flatnonzero(bad)[0])
            _fail(path, f"particle {i}: field radius is {radii[i]} (must be finite and at least {MIN_RADIUS_UM:g} "
                        "micrometres: radii are in micrometres)")
        sp = np.asarray(species[sl], dtype=np.float64)
        bad = ~(np.isfinite(sp) & (sp == np.round(sp)) & (sp >= 0) & (sp < limit))
        if bad.any():
            i = a + int(np.flatnonzero(bad)[0])
            suffix = f" (have {n_species} species)" if n_species is not None else ""
            _fail(path, f"particle {i}: field species is {species[i]}, not a known species index{suffix}")
    # Integer species keep their type (an int64 copy of 1e8 is 800 MB); others become integers.
    if species.dtype.kind not in "iu":
        species = species.astype(np.int64)
    return ParticleSet(np.ascontiguousarray(pos), np.ascontiguousarray(radii), np.ascontiguousarray(species))


def _real(path, name: str, values) -> np.ndarray:
    """``values`` as an array of real numbers (integers or floats), or an error naming ``name`` and its dtype
    (a complex, text, boolean or object array would be cast silently or not at all)."""
    arr = np.asarray(values)
    if arr.dtype.kind not in "iuf":
        _fail(path, f"{name} has dtype {arr.dtype}: expected real numbers (integers or floats)")
    return arr


# --- Opening: regular files only ------------------------------------------------------------------------------

_NOT_REGULAR = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
                (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))


def _check_regular(path, mode: int) -> None:
    if not stat.S_ISREG(mode):
        what = next((w for test, w in _NOT_REGULAR if test(mode)), "not a regular file")
        _fail(path, f"is {what}: a particle file must be a regular file")


def _open(path):
    """``path`` opened for binary reading with its size, checked to be a regular file before opening (a FIFO
    would block the reader forever; a directory or a device is no particle file) and again once open, without
    blocking (so that nothing swapped in between is read)."""
    try:
        _check_regular(path, os.stat(path).st_mode)
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    except FileNotFoundError:
        _fail(path, "no such file")
    except OSError as exc:  # permission denied, a path through a file, too many links, ...
        _fail(path, f"cannot be read: {exc.strerror or exc}")
    f = os.fdopen(fd, "rb")
    try:
        st = os.fstat(fd)
        _check_regular(path, st.st_mode)
    except BaseException:
        f.close()
        raise
    return f, st.st_size


_SIGNATURES = ((b"\x1f\x8b", "gzip-compressed: decompress it first"), (b"PK\x03\x04", "a zip archive"),
               (b"PK\x05\x06", "an empty zip archive"), (b"\x93NUMPY", "a numpy .npy array"),
               (b"ply", "a PLY file"))


def _looks_like(head: bytes) -> str:
    """What a file's first bytes say it is, as a parenthesis for a message (empty when they say nothing)."""
    return next((f" (it is {what})" for magic, what in _SIGNATURES if head.startswith(magic)), "")


# --- Text: CSV rows and ASCII PLY rows ------------------------------------------------------------------------

_NUMBER = re.compile(r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?|nan|inf(?:inity)?)", re.ASCII | re.IGNORECASE)


def _line_start(buf: bytes, k: int) -> int:
    """The byte offset of line ``k`` (0-based) of ``buf``, which holds at least ``k`` line breaks (counted 4 MiB
    at a time: no per-line work, no file-sized temporaries)."""
    pos, seen, step = 0, 0, 1 << 22
    while k > 0 and pos < len(buf):
        c = buf.count(b"\n", pos, pos + step)
        if seen + c >= k:
            chunk = np.frombuffer(buf, np.uint8, count=min(step, len(buf) - pos), offset=pos)
            return pos + int(np.flatnonzero(chunk == 10)[k - seen - 1]) + 1
        seen, pos = seen + c, pos + step
    return min(pos, len(buf))


def _table(path, text: str, first_line: int, columns: list[str], delimiter: str | None, what: str, fmt: str) -> np.ndarray:
    """``text`` (lines each ending in a line break) as an (n lines, len(columns)) float64 array, one number per
    column; else an error naming the first bad line by its number in the file (``first_line`` is the first's),
    the column and what is wrong. numpy parses; where it fails, or skips a line, a walk over the lines finds
    the culprit (and is the reference: it parses what numpy would not agree on)."""
    n, k = text.count("\n"), len(columns)
    if n == 0:
        return np.empty((0, k))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": the walk below names the line
            data = np.loadtxt(io.StringIO(text), delimiter=delimiter, comments=None, dtype=np.float64, ndmin=2)
        if data.shape == (n, k):
            return data
    except ValueError:
        pass
    names = ", ".join(columns)
    out = np.empty((n, k))
    for i, line in enumerate(text.split("\n")[:n]):  # only for a file numpy refused: the error path
        no = first_line + i
        if not line.strip():
            _fail(path, f"malformed {fmt}: line {no} is empty (expected {what}: {names})")
        tokens = line.split(delimiter) if delimiter else line.split()
        if len(tokens) != k:
            _fail(path, f"malformed {fmt}: line {no} holds {len(tokens)} values, expected {k} ({names})")
        for j, tok in enumerate(tokens):
            if not _NUMBER.fullmatch(tok.strip()):
                _fail(path, f"malformed {fmt}: line {no}: {columns[j]} is {tok.strip()[:40]!r}, not a number")
            out[i, j] = float(tok)
    return out


def _line_of(buf: bytes, offset: int) -> int:
    """The 1-based number of the line of ``buf`` that holds byte ``offset``."""
    return buf.count(b"\n", 0, offset) + 1


def _ends_with_line_break(path, raw: bytes, first_line: int = 1) -> None:
    """Text particle files end with a line break: a file cut inside its last line (a number cut short reads
    as another number) is refused rather than read wrong. ``first_line``: the number of ``raw``'s first line."""
    if raw and not raw.endswith(b"\n"):
        _fail(path, f"line {first_line - 1 + _line_of(raw, len(raw))} (the last) does not end with a line break: the "
                    "file looks truncated (end every line, the last included, with a line break)")


_CSV_COLUMNS = ("x", "y", "z", "radius_um", "species")


def _read_csv(path, f, size, scale_m):
    raw = f.read()
    try:
        text = raw.decode("utf-8").removeprefix("\ufeff")  # a byte-order mark (Excel's "CSV UTF-8") is no data
    except UnicodeDecodeError as exc:
        _fail(path, f"line {_line_of(raw, exc.start)} is not UTF-8 text{_looks_like(raw)}")
    _ends_with_line_break(path, raw)
    header, _, body = text.replace("\r\n", "\n").partition("\n")
    names = [h.strip().lower() for h in header.split(",")]
    unknown = [h for h in names if h not in _CSV_COLUMNS]
    if unknown:
        what = f"unknown column {unknown[0]!r}" if unknown[0] else "an empty column name"
        _fail(path, f"line 1: {what} in the header {header.strip()[:80]!r} (the columns are "
                    "x, y, z, radius_um and optionally species, named on the first line)")
    for name in names:
        if names.count(name) > 1:
            _fail(path, f"line 1: column {name!r} is named twice")
    for req in ("x", "y", "z", "radius_um"):
        if req not in names:
            _fail(path, f"line 1: the header must name column {req!r} (got {header.strip()[:80]!r})")
    body = body.rstrip() + "\n" if body.strip() else ""  # blank lines at the end are no rows
    data = _table(path, body, 2, names, ",", "a particle", "CSV")
    if data.shape[0] == 0:
        _fail(path, "the particle set is empty (no rows after the header line)")
    col = {n: data[:, i] for i, n in enumerate(names)}
    return np.column_stack([col["x"], col["y"], col["z"]]), col["radius_um"], col.get("species")


# --- PLY --------------------------------------------------------------------------------------------------------

_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4",
              "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4",
              "uint32": "u4", "float32": "f4", "float64": "f8"}
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_PLY_HEADER_MAX = 1 << 20
_PLY_KEYWORDS = "format, element, property, comment, obj_info or end_header"


@dataclass
class _Property:
    name: str
    type: str | None  # a key of _PLY_TYPES; None for a list
    line: int
    sizes: tuple[int, int] = (0, 0)  # a list's (count, item) sizes in bytes


@dataclass
class _Element:
    name: str
    count: int
    line: int
    props: list[_Property] = field(default_factory=list)

    def row_bytes(self) -> int:
        """Bytes per row in a binary file; for a list property, its count alone (the least a row takes)."""
        return sum(p.sizes[0] if p.type is None else int(_PLY_TYPES[p.type][1]) for p in self.props)

    def fixed(self) -> bool:
        return all(p.type is not None for p in self.props)


def _ply_type(path, no: int, name: str, t: str) -> str:
    if t not in _PLY_TYPES:
        _fail(path, f"line {no}: property {name!r} has unknown type {t!r} (PLY types: char, uchar, short, ushort, "
                    "int, uint, float, double, or int8 ... float64)")
    return t


def _ply_header(path, f, size):
    """(format, elements, byte offset of the body, line number of end_header) of a PLY file's header."""
    head = f.read(min(size, _PLY_HEADER_MAX))
    if re.match(rb"ply[ \t]*\r?\n", head) is None:
        _fail(path, f"not a PLY file: its first line is not 'ply'{_looks_like(head)}")
    end = re.search(rb"\nend_header[ \t\r]*\n", head) or (re.search(rb"\nend_header[ \t\r]*\Z", head) if len(head) == size else None)
    if end is None:
        _fail(path, "malformed PLY: no end_header line " + (f"in the first {_PLY_HEADER_MAX >> 20} MiB" if size > len(head)
                                                            else "(the file is cut short, or not a PLY file)"))
    try:
        lines = head[:end.start()].decode("ascii").split("\n")
    except UnicodeDecodeError as exc:
        _fail(path, f"line {_line_of(head, exc.start)}: the PLY header is not ASCII text")
    fmt, elements = None, []
    for no, line in enumerate(lines[1:], 2):  # a header's few lines: a loop is fine
        words = line.split()
        if not words:
            _fail(path, f"line {no} is empty (a PLY header has no blank lines)")
        key = words[0]
        if key in ("comment", "obj_info"):
            continue
        if key == "format":
            if fmt is not None or elements:
                _fail(path, f"line {no}: a second 'format' line, or one after an element")
            if len(words) != 3 or words[1] not in _PLY_FORMATS or words[2] not in ("1.0", "1"):
                _fail(path, f"line {no}: unknown format {' '.join(words[1:])[:60]!r} (expected 'ascii 1.0', "
                            "'binary_little_endian 1.0' or 'binary_big_endian 1.0')")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not re.fullmatch(r"\d{1,30}", words[2]):
                _fail(path, f"line {no}: {line.strip()[:60]!r}: an element needs a name and a whole number of rows "
                            "(e.g. 'element vertex 1000')")
            if any(e.name == words[1] for e in elements):
                _fail(path, f"line {no}: element {words[1]!r} is declared twice")
            elements.append(_Element(words[1], int(words[2]), no))
        elif key == "property":
            if not elements:
                _fail(path, f"line {no}: a property before any element")
            el = elements[-1]
            if len(words) == 5 and words[1] == "list":
                ct, it = _ply_type(path, no, words[4], words[2]), _ply_type(path, no, words[4], words[3])
                if _PLY_TYPES[ct][0] == "f":
                    _fail(path, f"line {no}: list {words[4]!r} has a non-integer count type {ct!r}")
                prop = _Property(words[4], None, no, (int(_PLY_TYPES[ct][1]), int(_PLY_TYPES[it][1])))
            elif len(words) == 3 and words[1] != "list":
                prop = _Property(words[2], _ply_type(path, no, words[2], words[1]), no)
            else:
                _fail(path, f"line {no}: {line.strip()[:60]!r}: expected 'property TYPE NAME' or "
                            "'property list COUNT_TYPE ITEM_TYPE NAME'")
            if any(p.name.lower() == prop.name.lower() for p in el.props):
                _fail(path, f"line {no}: element {el.name!r} has property {prop.name!r} twice")
            el.props.append(prop)
        else:
            _fail(path, f"line {no}: {line.strip()[:40]!r} is not a PLY header line (expected {_PLY_KEYWORDS})")
    if fmt is None:
        _fail(path, "malformed PLY: no 'format' line in the header")
    return fmt, elements, end.end(), len(lines) + 1


def _ply_vertex(path, elements: list[_Element]) -> _Element:
    """The vertex element, checked to hold what particles need (one scalar per property)."""
    vertex = next((e for e in elements if e.name == "vertex"), None)
    if vertex is None:
        _fail(path, "no 'vertex' element in the PLY header (particles are the vertices of a point cloud)")
    for p in vertex.props:
        if p.type is None:
            _fail(path, f"line {p.line}: vertex property {p.name!r} is a list ('property list ...'), which particle "
                        "files do not support: give each vertex one number per property (x, y, z, radius or "
                        "pscale, species)")
    names = [p.name.lower() for p in vertex.props]
    for req in ("x", "y", "z"):
        if req not in names:
            _fail(path, f"vertex element (line {vertex.line}) has no {req!r} property")
    if "radius" in names and "pscale" in names:
        _fail(path, "vertex element has both 'radius' (micrometres) and 'pscale' (scene units): keep one")
    if "radius" not in names and "pscale" not in names:
        _fail(path, "vertex element has neither a 'radius' (micrometres) nor a 'pscale' (scene units) property")
    if vertex.count == 0:
        _fail(path, f"vertex element (line {vertex.line}) has 0 rows: the particle set is empty")
    return vertex


def _rows_msg(e: _Element, held) -> str:
    return f"element {e.name!r} (line {e.line}) declares {e.count} rows but the file holds {held}"


def _read_ply_ascii(path, f, size, elements, vertex, offset, header_lines):
    f.seek(offset)
    body = f.read()
    held, first, before = body.count(b"\n"), header_lines + 1, 0
    _ends_with_line_break(path, body, first)
    for e in elements:  # too few lines for an element: refused before anything is parsed or allocated
        if held - before < e.count:
            _fail(path, f"{_rows_msg(e, max(held - before, 0))}: the file is cut short, or the count is wrong")
        if e is vertex:
            start = before
        before += e.count
    end = _line_start(body, before)
    if body[end:].strip():
        _fail(path, f"line {first + before}: data after the last element ({elements[-1].name!r}, line "
                    f"{elements[-1].line}): a count in the header is too small, or the file has extra data")
    a, b = _line_start(body, start), _line_start(body, start + vertex.count)
    text = body[a:b].decode("latin-1").replace("\r", " ")  # numbers are ASCII: any other byte fails to parse
    data = _table(path, text, first + start, [p.name for p in vertex.props], None, "a vertex row", "PLY")
    return {p.name.lower(): data[:, i] for i, p in enumerate(vertex.props)}


def _read_ply_binary(path, f, size, fmt, elements, vertex, offset):
    order = _PLY_FORMATS[fmt]
    at = offset
    for e in elements[:elements.index(vertex)]:
        if not e.fixed() and e.count:
            _fail(path, f"element {e.name!r} (line {e.line}) has list properties and precedes 'vertex' in a binary "
                        "PLY, which particle files do not support: write the vertex element first")
        at += e.count * e.row_bytes()
    dtype = np.dtype([(p.name, order + _PLY_TYPES[p.type]) for p in vertex.props])
    need, left = vertex.count * dtype.itemsize, size - at
    if left < need:  # before anything of the declared size is allocated
        left = max(left, 0)
        _fail(path, f"{_rows_msg(vertex, left // dtype.itemsize)} ({left} bytes after the header, {dtype.itemsize} "
                    "per row): the file is cut short, or the count is wrong")
    after = elements[elements.index(vertex) + 1:]
    rest, least = left - need, sum(e.count * e.row_bytes() for e in after)
    if rest < least:
        _fail(path, f"the elements after 'vertex' need at least {least} bytes but {rest} follow it: the file is "
                    "cut short, or a count is wrong")
    if rest > least and all(e.fixed() or not e.count for e in after):
        _fail(path, f"{rest - least} bytes of extra data after the last element: a count in the header is too "
                    "small, or the file has extra data")
    raw = np.empty(need, np.uint8)
    f.seek(at)
    if f.readinto(raw) != need:
        _fail(path, "the file changed while it was read")
    rows = raw.view(dtype)
    data = {p.name.lower(): rows[p.name].astype(rows[p.name].dtype.newbyteorder("=")) for p in vertex.props}
    for name in ("x", "y", "z", "radius", "pscale"):
        v = data.get(name)
        if v is not None and v.dtype.kind == "f":
            tiny = np.abs(v) < np.finfo(v.dtype).tiny
            tiny &= v != 0
            if tiny.any():  # never in particle data; what floats read in the wrong byte order look like
                i = int(np.flatnonzero(tiny)[0])
                _fail(path, f"particle {i}: field {name} is {v[i]:.3g}, a subnormal number: the byte order in the format "
                            f"line (format {fmt}) is likely wrong")
    return data


def _read_ply(path, f, size, scale_m):
    fmt, elements, offset, header_lines = _ply_header(path, f, size)
    vertex = _ply_vertex(path, elements)
    if _PLY_FORMATS[fmt] is None:
        data = _read_ply_ascii(path, f, size, elements, vertex, offset, header_lines)
    else:
        data = _read_ply_binary(path, f, size, fmt, elements, vertex, offset)
    if "radius" in data:
        radii = data["radius"].astype(np.float64)
    else:
        radii = data["pscale"].astype(np.float64) * scale_m * 1e6  # scene units -> micrometres
    return np.column_stack([data["x"], data["y"], data["z"]]), radii, data.get("species")


# --- numpy ------------------------------------------------------------------------------------------------------

_NPY_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def _npy_array(path, open_member, available: int, label: str) -> np.ndarray:
    """The .npy array that ``open_member()`` opens (``available`` bytes long): its header checked against the
    bytes that follow before anything is allocated, its dtype real numbers, never unpickled."""
    with open_member() as fp:
        head = fp.read(8)
        if len(head) < 8 or not head.startswith(b"\x93NUMPY"):
            _fail(path, f"{label} is not a numpy .npy array{_looks_like(head)}")
        version = (head[6], head[7])
        if version not in _NPY_HEADERS:
            _fail(path, f"{label}: unsupported .npy format version {version[0]}.{version[1]} (numpy.save writes 1.0)")
        try:
            shape, _, dtype = _NPY_HEADERS[version](fp)
        except ValueError as exc:
            _fail(path, f"{label}: malformed .npy header ({exc})")
        if dtype.hasobject or dtype.kind not in "iuf":
            never = "; Python objects are never loaded" if dtype.hasobject else ""
            _fail(path, f"{label} has dtype {dtype}: expected real numbers (integers or floats{never})")
        nbytes, left = math.prod(shape) * dtype.itemsize, available - fp.tell()
        if nbytes != left:
            _fail(path, f"{label}'s header declares shape {shape} ({nbytes} bytes of {dtype}) but {left} bytes "
                        f"follow: {'the file is cut short' if left < nbytes else 'extra data after the array'}")
    with open_member() as fp:
        return np.lib.format.read_array(fp, allow_pickle=False)


@contextlib.contextmanager
def _rewound(f):
    """The open file from its start, for a ``with`` that must not close it."""
    f.seek(0)
    yield f


def _read_npy(path, f, size, scale_m):
    arr = _npy_array(path, lambda: _rewound(f), size, "the .npy array")
    if arr.ndim != 2 or arr.shape[1] not in (4, 5):
        _fail(path, f"expected an (n, 4) or (n, 5) array x, y, z, radius_um[, species], got shape {arr.shape}")
    return arr[:, :3], arr[:, 3], arr[:, 4] if arr.shape[1] == 5 else None


#: Deflate expands at most ~1032-fold: a member claiming more than this is damaged or crafted (a zip bomb).
_DEFLATE_MAX_RATIO = 1100


def _read_npz(path, f, size, scale_m):
    head = f.read(8)
    if head[:4] not in (b"PK\x03\x04", b"PK\x05\x06"):
        _fail(path, f"is not an npz archive{_looks_like(head)}: an .npz is a zip of .npy arrays, as numpy.savez writes")
    f.seek(0)
    try:
        z = zipfile.ZipFile(f)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        _fail(path, f"is not a readable npz archive (a zip of .npy arrays, as numpy.savez writes): {exc}")
    with z:
        names = {n.removesuffix(".npy") for n in z.namelist() if n.endswith(".npy")}
        for key in ("positions", "radii_um"):
            if key not in names:
                _fail(path, f"missing array {key!r} (has {sorted(names)})")
        out = []
        for key in ("positions", "radii_um", "species"):
            if key not in names:
                out.append(None)
                continue
            info = z.getinfo(key + ".npy")
            if info.compress_size > size or info.file_size > _DEFLATE_MAX_RATIO * info.compress_size + 4096:
                _fail(path, f"array {key!r} claims {info.file_size} bytes from {info.compress_size} compressed: the "
                            "archive is damaged")
            try:
                out.append(_npy_array(path, lambda info=info: z.open(info), info.file_size, f"array {key!r}"))
            except ParticleFileError:
                raise
            except (zipfile.BadZipFile, OSError, ValueError, EOFError, RuntimeError, NotImplementedError) as exc:
                _fail(path, f"array {key!r} cannot be read: the archive is damaged ({exc})")
    return tuple(out)


_READERS = {".npz": _read_npz, ".npy": _read_npy, ".csv": _read_csv, ".ply": _read_ply}


def load_particles(path, *, scale_m: float = 1.0, n_species: int | None = None) -> ParticleSet:
    """Read and validate a particle set (module docs)."""
    path = os.fspath(path)
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise ValueError(f"invalid scale_m = {scale_m}: must be finite and > 0")
    suffix = pathlib.Path(path).suffix.lower()
    f, size = _open(path)
    with f:
        reader = _READERS.get(suffix)
        if reader is None:
            _fail(path, f"unknown particle file type {suffix!r} (use .npz, .npy, .csv or .ply)")
        if size == 0:
            _fail(path, "the file is empty (0 bytes)")
        try:
            pos, radii, species = reader(path, f, size, scale_m)
        except OSError as exc:  # an I/O error while reading
            _fail(path, f"cannot be read: {exc.strerror or exc}")
    return _validate(path, pos, radii, species, n_species)


def save_particles(path, pset: ParticleSet, *, scale_m: float = 1.0, binary: bool = True) -> None:
    """Write a particle set in the format given by the file suffix (PLY gets ``radius`` in micrometres)."""
    path = os.fspath(path)
    p = _validate(path, pset.positions, pset.radii_um, pset.species, None)
    suffix = pathlib.Path(path).suffix.lower()
    if suffix == ".npz":
        np.savez(path, positions=p.positions, radii_um=p.radii_um, species=p.species)
    elif suffix == ".npy":
        np.save(path, np.column_stack([p.positions, p.radii_um, p.species]))
    elif suffix == ".csv":
        np.savetxt(path, np.column_stack([p.positions, p.radii_um, p.species]), delimiter=",",
                   header="x,y,z,radius_um,species", comments="", fmt=["%.17g"] * 4 + ["%d"])
    elif suffix == ".ply":
        import meshio  # noqa: PLC0415

        meshio.write(path, meshio.Mesh(p.positions, [], point_data={"radius": p.radii_um, "species": p.species.astype(np.int32)}),
                     file_format="ply", binary=binary)
    else:
        _fail(path, f"unknown particle file type {suffix!r} (use .npz, .npy, .csv or .ply)")


__all__ = ["ParticleFileError", "ParticleSet", "load_particles", "save_particles"]
