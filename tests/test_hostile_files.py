"""Hostile particle files (issue 44): each row of ``CASES`` is one file a user can hand to ``motes particles``,
to the ``discrete`` medium's ``filename`` (through ``motes render``) or to ``motes.load_particles``, with the
outcome it must get — one line ``motes: error: ...`` naming the file and what is wrong, exit status 2, no
traceback; ``ParticleFileError`` from the API; or the documented behaviour (a CSV's byte-order mark is
ignored) — and words the message must hold. Nothing may hang (a FIFO), read silently wrong (a header that
disagrees with its body) or surface as a Python exception's name. Then property tests: headers against
bodies, truncated and corrupted files, and the numbers of a CSV.

    .venv/bin/python tests/test_hostile_files.py     # prints the table (runs every case)
"""

from __future__ import annotations

import contextlib
import gzip
import io
import os
import pathlib
import re
import sys
import threading
import warnings
from dataclasses import dataclass
from typing import Callable
from unittest import mock

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import motes
from motes.particle_io import MIN_RADIUS_UM, ParticleFileError

from conftest import hsettings

HEADER = ("ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty {t} x\nproperty {t} y\nproperty {t} z\n"
          "property {t} radius\nend_header\n")
ROWS = np.array([[0.0, 0.0, 0.0, 1.5], [1.0, 2.0, 3.0, 2.5], [-1.0, 0.5, 0.25, 4.0]])


def ply(rows=ROWS, fmt: str = "ascii", n: int | str | None = None, t: str = "double", header: str = HEADER) -> bytes:
    """A PLY of ``rows`` (x y z radius) declaring ``n`` vertices (default: as many as it holds)."""
    head = header.format(fmt=fmt, n=len(rows) if n is None else n, t=t).encode()
    if fmt == "ascii":
        return head + b"".join(" ".join(repr(float(v)) for v in r).encode() + b"\n" for r in rows)
    order = "<" if fmt == "binary_little_endian" else ">"
    return head + np.asarray(rows, dtype=order + {"double": "f8", "float": "f4"}[t]).tobytes()


def csv(rows=ROWS, header: str = "x,y,z,radius_um") -> bytes:
    return (header + "\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in rows)).encode()


def npy(arr, **kw) -> bytes:
    f = io.BytesIO()
    np.save(f, arr, **kw)
    return f.getvalue()


def npz(**arrays) -> bytes:
    f = io.BytesIO()
    np.savez(f, **arrays)
    return f.getvalue()


def _npy_with_shape(shape, body: bytes) -> bytes:
    """A version 1.0 .npy of float64 whose header declares ``shape``, followed by ``body``."""
    header = f"{{'descr': '<f8', 'fortran_order': False, 'shape': {shape!r}, }}".encode()
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + body


@dataclass
class Case:
    """One hostile file. ``kind``: "particles" (``motes particles FILE``: exit 2, one line), "render" (the file as
    the medium's ``filename`` through ``motes render``: exit 2, one line), "api" (``load_particles`` raises
    ``ParticleFileError``), "ok" (``motes particles`` reads it: exit 0, the count in ``words``). ``make(dir)``
    creates the input and returns the path (or, for "render", the ``filename`` value) to give."""

    name: str
    what: str
    kind: str
    words: list[str]
    make: Callable[[pathlib.Path], str]


def file(name: str, data: bytes | Callable[[], bytes]):
    def make(d: pathlib.Path) -> str:
        (d / name).write_bytes(data() if callable(data) else data)
        return str(d / name)
    return make


def fifo(name: str):
    def make(d: pathlib.Path) -> str:
        os.mkfifo(d / name)
        return str(d / name)
    return make


def folder(name: str):
    def make(d: pathlib.Path) -> str:
        (d / name).mkdir()
        return str(d / name)
    return make


def relative(make_file, name: str):
    """For "render": the file made in the scene's folder, given by its bare name."""
    def make(d: pathlib.Path) -> str:
        if make_file is not None:
            make_file(d)
        return name
    return make


BIN = ply(fmt="binary_little_endian")
FACE_FIRST = ("ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
              "element vertex {n}\nproperty {t} x\nproperty {t} y\nproperty {t} z\nproperty {t} radius\nend_header\n")
CASES = [
    # The classes, through `motes particles FILE`.
    Case("fifo", "a FIFO named grains.ply (used to block forever)", "particles", ["grains.ply", "FIFO", "regular file"],
         fifo("grains.ply")),
    Case("ply_rows_short", "ASCII PLY declaring 5 vertices holding 2 rows (used to read 2)", "particles",
         ["rows.ply", "declares 5 rows", "holds 2"], file("rows.ply", ply(ROWS[:2], n=5))),
    Case("ply_rows_extra", "ASCII PLY declaring 1 vertex holding 3 rows", "particles",
         ["extra.ply", "line 10", "data after the last element"], file("extra.ply", ply(n=1))),
    Case("ply_list_property", "PLY whose radius is `property list uchar float` (used to be a KeyError)", "particles",
         ["list.ply", "line 7", "'radius' is a list"],
         file("list.ply", ply(ROWS[:1], t="double").replace(b"property double radius", b"property list uchar float radius")
              .replace(b" 1.5\n", b" 1 1.5\n"))),
    Case("ply_unknown_type", "PLY with `property float128 radius`", "particles", ["line 7", "unknown type 'float128'"],
         file("type.ply", ply(ROWS[:1]).replace(b"double radius", b"float128 radius"))),
    Case("ply_count_huge", "ASCII PLY declaring 3e12 vertices (used to be a bare MemoryError)", "particles",
         ["huge.ply", "declares 3000000000000 rows", "holds 3"], file("huge.ply", ply(n=3 * 10**12))),
    Case("ply_binary_count_huge", "binary PLY declaring 1e15 vertices (refused before allocating)", "particles",
         ["declares 1000000000000000 rows", "cut short"], file("bhuge.ply", ply(fmt="binary_little_endian", n=10**15))),
    Case("ply_count_negative", "PLY declaring -5 vertices", "particles", ["line 3", "whole number"],
         file("neg.ply", ply(n=-5))),
    Case("ply_binary_truncated", "binary PLY cut 7 bytes short", "particles", ["declares 3 rows", "holds 2", "cut short"],
         file("cut.ply", BIN[:-7])),
    Case("ply_binary_extra", "binary PLY with 2 extra bytes", "particles", ["2 bytes of extra data"], file("more.ply", BIN + b"xx")),
    Case("ply_binary_wrong_endian", "little-endian data under `format binary_big_endian`", "particles",
         ["subnormal", "byte order", "binary_big_endian"],
         file("endian.ply", BIN.replace(b"binary_little_endian", b"binary_big_endian"))),
    Case("ply_format_misspelt", "`format binary_little_endain 1.0`", "particles", ["line 2", "unknown format"],
         file("fmt.ply", BIN.replace(b"binary_little_endian", b"binary_little_endain"))),
    Case("ply_no_end_header", "PLY header without end_header (meshio loops forever on it)", "particles",
         ["end_header"], file("noend.ply", ply().replace(b"end_header\n", b""))),
    Case("ply_gzip", "gzip'd PLY named .ply", "particles", ["not a PLY file", "gzip"], file("gz.ply", gzip.compress(BIN))),
    Case("ply_not_ply", "a text file named .ply", "particles", ["not a PLY file"], file("text.ply", b"hello\n")),
    Case("ply_ascii_not_number", "ASCII PLY with `1 x 1 2` on line 10", "particles", ["line 10", "y is 'x'", "not a number"],
         file("nan.ply", ply().replace(b"1.0 2.0 3.0", b"1 x 1"))),
    Case("ply_ascii_short_row", "ASCII PLY with a row of 3 values", "particles", ["line 10", "3 values, expected 4"],
         file("row.ply", ply().replace(b"1.0 2.0 3.0 2.5", b"1.0 2.0 3.0"))),
    Case("ply_ascii_cut_mid_number", "ASCII PLY cut inside its last number (4.0 -> 4.)", "particles",
         ["line 11", "line break", "truncated"], file("midnum.ply", ply()[:-2])),
    Case("ply_no_vertex", "PLY with only a face element", "particles", ["no 'vertex' element"],
         file("face.ply", b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n")),
    Case("ply_radius_and_pscale", "PLY with both radius and pscale", "particles", ["both 'radius'", "'pscale'"],
         file("both.ply", ply(ROWS[:1]).replace(b"end_header", b"property double pscale\nend_header").replace(b"1.5\n", b"1.5 0.1\n"))),
    Case("ply_list_before_vertex", "binary PLY with a face element (list) before the vertices", "particles",
         ["'face'", "precedes 'vertex'"], file("ff.ply", ply(fmt="binary_little_endian", header=FACE_FIRST))),
    Case("ply_header_keyword", "PLY header line `colour red`", "particles", ["line 3", "not a PLY header line"],
         file("kw.ply", ply().replace(b"element vertex", b"colour red\nelement vertex"))),
    # CSV
    Case("csv_bom", "CSV with a UTF-8 byte-order mark (used to be refused)", "ok", ["3 particles"],
         file("bom.csv", b"\xef\xbb\xbf" + csv())),
    Case("csv_header_wrong_name", "CSV header `x,y,z,radius`", "particles", ["line 1", "unknown column 'radius'", "radius_um"],
         file("hdr.csv", csv(header="x,y,z,radius"))),
    Case("csv_header_misspelt", "CSV header naming `speceis` (used to be ignored: every species 0)", "particles",
         ["unknown column 'speceis'"], file("sp.csv", csv(np.column_stack([ROWS, [0, 1, 1]]), header="x,y,z,radius_um,speceis"))),
    Case("csv_no_header", "CSV without a header line", "particles", ["line 1", "unknown column '0.0'"],
         file("nohdr.csv", csv()[len("x,y,z,radius_um\n"):])),
    Case("csv_column_twice", "CSV header naming x twice", "particles", ["column 'x' is named twice"],
         file("twice.csv", csv(np.column_stack([ROWS, ROWS[:, :1]]), header="x,y,z,radius_um,x"))),
    Case("csv_nan", "CSV with y = nan", "particles", ["particle 1", "field y is nan"],
         file("nan.csv", csv().replace(b"1.0,2.0", b"1.0,nan"))),
    Case("csv_inf_radius", "CSV with radius inf", "particles", ["particle 2", "field radius is inf"],
         file("inf.csv", csv().replace(b"4.0", b"inf"))),
    Case("csv_negative_radius", "CSV with radius -2.5", "particles", ["particle 1", "field radius is -2.5"],
         file("neg.csv", csv().replace(b"2.5", b"-2.5"))),
    Case("csv_subnormal_radius", "CSV with radius 1e-320 (used to fail later, in the grid, without the file's name)",
         "particles", ["particle 1", "field radius is 1e-320", "at least 1e-09 micrometres"],
         file("tiny.csv", csv().replace(b"2.5", b"1e-320"))),
    Case("csv_short_row", "CSV with a row of 3 values", "particles", ["line 3", "3 values, expected 4"],
         file("row.csv", csv().replace(b",2.5\n", b"\n"))),
    Case("csv_blank_line", "CSV with a blank line between rows", "particles", ["line 3 is empty"],
         file("blank.csv", csv().replace(b"0.0,1.5\n", b"0.0,1.5\n\n"))),
    Case("csv_cut_mid_number", "CSV cut inside its last number", "particles", ["line 4", "line break"], file("cut.csv", csv()[:-2])),
    Case("csv_not_utf8", "CSV in Latin-1 (a header with an accent)", "particles", ["line 1", "not UTF-8"],
         file("latin.csv", "x,y,z,radius_um,é\n".encode("latin-1"))),
    # NumPy
    Case("npz_not_zip", "a text file named .npz (used to advise allow_pickle)", "particles", ["not an npz archive"],
         file("text.npz", b"hello\n")),
    Case("npz_is_npy", "a .npy array named .npz", "particles", ["not an npz archive", ".npy array"],
         file("arr.npz", npy(np.ones((3, 4))))),
    Case("npz_missing_array", "an .npz without radii_um", "particles", ["missing array 'radii_um'"],
         file("miss.npz", npz(positions=np.ones((3, 3))))),
    Case("npz_wrong_shape", "an .npz with positions of shape (3, 2)", "particles", ["positions", "(n, 3)", "(3, 2)"],
         file("shape.npz", npz(positions=np.ones((3, 2)), radii_um=np.ones(3)))),
    Case("npz_object_array", "an .npz whose positions are Python objects", "particles", ["'positions'", "dtype object", "never loaded"],
         file("obj.npz", lambda: npz(positions=np.array([[1, 2, 3]], dtype=object), radii_um=np.ones(1)))),
    Case("npz_complex", "an .npz with complex positions (used to drop the imaginary part)", "particles", ["complex128"],
         file("cplx.npz", npz(positions=np.ones((1, 3)) * 1j, radii_um=np.ones(1)))),
    Case("npz_text_radii", "an .npz with radii as text", "particles", ["'radii_um'", "<U1"],
         file("text_r.npz", npz(positions=np.ones((1, 3)), radii_um=np.array(["5"])))),
    Case("npy_truncated", "a .npy cut 9 bytes short", "particles", ["declares shape (100, 4)", "3191 bytes", "cut short"],
         file("cut.npy", npy(np.ones((100, 4)))[:-9])),
    Case("npy_header_huge", "a .npy whose header claims 1e12 rows (refused before allocating)", "particles",
         ["declares shape (1000000000000, 4)", "cut short"], file("huge.npy", _npy_with_shape((10**12, 4), np.ones(4).tobytes()))),
    Case("npy_object", "a .npy of Python objects", "particles", ["dtype object", "never loaded"],
         file("obj.npy", lambda: npy(np.array([[1, 2, 3, 4]], dtype=object), allow_pickle=True))),
    # The path itself.
    Case("empty_file", "an empty (0-byte) .ply", "particles", ["empty (0 bytes)"], file("empty.ply", b"")),
    Case("directory", "a directory named grains.npz", "particles", ["grains.npz", "is a directory"], folder("grains.npz")),
    Case("missing", "a file that does not exist", "particles", ["none.ply", "no such file"], lambda d: str(d / "none.ply")),
    Case("unreadable", "a file without read permission", "particles", ["noread.csv", "Permission denied"],
         file("noread.csv", csv())),
    Case("unknown_suffix", "a .txt file", "particles", ["unknown particle file type '.txt'"], file("p.txt", b"1 2 3\n")),
    Case("api_fifo", "load_particles of a FIFO", "api", ["grains.csv", "FIFO"], fifo("grains.csv")),
    # The discrete medium's filename, through `motes render`.
    Case("filename_empty", 'filename = "" (used to resolve to a folder)', "render", ["filename is empty"], relative(None, "")),
    Case("filename_blank", 'filename = "   "', "render", ["filename is empty"], relative(None, "   ")),
    Case("filename_directory", 'filename = "sub", a folder next to the scene', "render", ["filename = 'sub'", "is a directory"],
         relative(folder("sub"), "sub")),
    Case("filename_fifo", "filename naming a FIFO next to the scene", "render", ["filename = 'pipe.npz'", "FIFO"],
         relative(fifo("pipe.npz"), "pipe.npz")),
    Case("filename_relative_missing", "filename = \"absent.npz\" (relative, nowhere)", "render",
         ["filename = 'absent.npz'", "no such file", "scene file's folder"], relative(None, "absent.npz")),
    Case("filename_ply_rows_short", "filename of an ASCII PLY declaring 5 vertices holding 2", "render",
         ["filename = 'rows.ply'", "declares 5 rows", "holds 2"], relative(file("rows.ply", ply(ROWS[:2], n=5)), "rows.ply")),
]

#: What no message may hold: a traceback, a Python exception's name, unsafe advice.
FORBIDDEN = re.compile(r"Traceback|\b\w+(Error|Exception):|allow_pickle|pickle\.load")


def _scene(filename: str) -> str:
    from test_malformed import scene_xml  # noqa: PLC0415  (a cube holding a medium of the given parameters)

    return scene_xml({"filename": filename})


def _release_fifos(d: pathlib.Path, hung: list) -> None:
    """The watchdog: a reader blocked on a FIFO under ``d`` is released by opening its other end."""
    for p in d.rglob("*"):
        if p.is_fifo():
            hung.append(p.name)
            with contextlib.suppress(OSError):
                os.close(os.open(p, os.O_WRONLY | os.O_NONBLOCK))


def run_case(case: Case, d: pathlib.Path) -> tuple[str, str]:
    """(outcome, message) of one case: "exit N" with what the command printed (less progress lines), an
    exception's type and message, or "hang" where the watchdog had to release a FIFO."""
    target = case.make(d)
    hung: list = []
    watchdog = threading.Timer(20.0, _release_fifos, (d, hung))
    watchdog.start()
    denied = contextlib.nullcontext()
    if case.name == "unreadable":
        os.chmod(target, 0)
        if os.geteuid() == 0:  # root reads anything: the refusal is simulated where the OS would give it
            denied = mock.patch("motes.particle_io.os.open", side_effect=PermissionError(13, "Permission denied"))
    try:
        with denied:
            outcome, msg = _outcome(case, target, d)
    finally:
        watchdog.cancel()
    return ("hang" if hung else outcome), msg


def _outcome(case: Case, target: str, d: pathlib.Path) -> tuple[str, str]:
    from motes import cli  # noqa: PLC0415

    if case.kind == "api":
        try:
            motes.load_particles(target)
        except Exception as e:  # noqa: BLE001 - the outcome is what we report
            return type(e).__name__, str(e)
        return "no error", ""
    argv = ["particles", target]
    if case.kind == "render":
        (d / "scene.xml").write_text(_scene(target))
        argv = ["render", str(d / "scene.xml"), "-m", "scalar_rgb", "-s", "1", "-o", str(d / "out.exr")]
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        rc = cli.main(argv)
    if rc == 0:
        return "exit 0", out.getvalue().splitlines()[0]
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip() and not ln.startswith(("motes: load", "  ["))]
    return f"exit {rc}", "\n".join(lines)


def test_cases_are_many_and_named_once():
    assert len(CASES) >= 50 and len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_hostile_file(case: Case, tmp_path):
    if case.kind == "render":
        pytest.importorskip("mitsuba")
    outcome, msg = run_case(case, tmp_path)
    if case.kind == "ok":
        assert outcome == "exit 0", msg
    elif case.kind == "api":
        assert outcome == "ParticleFileError", (outcome, msg)
    else:
        assert outcome == "exit 2", msg
        assert msg.startswith("motes: error: ") and "\n" not in msg and "Traceback" not in msg, msg
    assert all(w in msg for w in case.words), msg
    if case.kind != "render":  # Mitsuba's loader names the plugin's exception type ("ValueError: ...")
        assert not FORBIDDEN.search(msg), msg


def table() -> str:
    import tempfile  # noqa: PLC0415

    rows = ["| # | input | outcome | message |", "|---|---|---|---|"]
    for i, case in enumerate(CASES, 1):
        with tempfile.TemporaryDirectory() as d:
            outcome, msg = run_case(case, pathlib.Path(d))
        where = {"particles": "`motes particles`", "ok": "`motes particles`", "render": "`motes render`", "api": "API"}[case.kind]
        msg = msg.replace(d, "<tmp>").replace('failed to instantiate medium plugin of type "discrete": ', "")
        msg = msg.replace("|", "\\|")
        rows.append(f"| {i} | {case.what} ({where}) | {outcome} | {msg} |")
    return "\n".join(rows)


# --- Properties -------------------------------------------------------------------------------------------------

PLY_FORMATS = ["ascii", "binary_little_endian", "binary_big_endian"]
finite = st.floats(-1e6, 1e6, allow_nan=False, allow_subnormal=False, width=32)
radius = st.floats(2.0**-10, 1e4, width=32)
row = st.tuples(finite, finite, finite, radius)


def _load(path: pathlib.Path, **kw):
    """load_particles with warnings as errors: a hostile file may make nothing but a ParticleFileError."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return motes.load_particles(path, **kw)


@hsettings(150)
@given(fmt=st.sampled_from(PLY_FORMATS), t=st.sampled_from(["double", "float"]), rows=st.lists(row, max_size=5),
       delta=st.sampled_from([0, 0, 0, -1, 1, 2, -7, 10**13]), extra=st.sampled_from([b"", b"", b"\n  \n", b"0", b"0 0 0 1\n", b"\x00"]))
def test_ply_header_counts_against_the_body(tmp_path_factory, fmt, t, rows, delta, extra):
    """A PLY declaring ``len(rows) + delta`` vertices and holding ``rows`` plus ``extra`` bytes (in ASCII blank
    lines, or one more row) loads exactly the rows it holds when the count is theirs and nothing else follows,
    else it is refused with ParticleFileError — never read short, never another exception."""
    rows = np.array(rows, dtype=np.float64).reshape(-1, 4)
    path = tmp_path_factory.mktemp("ply") / "p.ply"
    path.write_bytes(ply(rows, fmt=fmt, n=len(rows) + delta, t=t) + extra)
    held, clean = rows, extra == b""
    if fmt == "ascii" and extra == b"0 0 0 1\n":
        held, clean = np.vstack([rows, [0, 0, 0, 1]]), True
    clean = clean or (fmt == "ascii" and not extra.strip())
    if len(rows) + delta == len(held) > 0 and clean:
        p = _load(path)
        np.testing.assert_array_equal(np.column_stack([p.positions, p.radii_um]), held)
    else:
        with pytest.raises(ParticleFileError, match="p.ply"):
            _load(path)


VALID = {"ascii.ply": ply(), "le.ply": ply(fmt="binary_little_endian", t="float"), "be.ply": ply(fmt="binary_big_endian"),
         "p.csv": csv(np.column_stack([ROWS, [0, 1, 2]]), header="x,y,z,radius_um,species"),
         "p.npy": npy(np.column_stack([ROWS, [0, 1, 2]])),
         "p.npz": npz(positions=ROWS[:, :3], radii_um=ROWS[:, 3], species=np.arange(3))}


@hsettings(150)
@given(name=st.sampled_from(sorted(VALID)), cut=st.floats(0.0, 1.0, exclude_max=True))
def test_truncated_files_are_refused(tmp_path_factory, name, cut):
    """A valid file cut anywhere: a PLY or NumPy file (which declare their sizes) is always refused; a CSV (which
    does not) is refused or reads exactly its first rows — never a shortened number."""
    data = VALID[name]
    path = tmp_path_factory.mktemp("cut") / name
    path.write_bytes(data[: int(cut * len(data))])
    if not name.endswith(".csv"):
        with pytest.raises(ParticleFileError, match=name):
            _load(path)
        return
    try:
        p = _load(path)
    except ParticleFileError as exc:
        assert name in str(exc)
    else:
        k = len(p)
        np.testing.assert_array_equal(np.column_stack([p.positions, p.radii_um]), ROWS[:k])
        np.testing.assert_array_equal(p.species, [0, 1, 2][:k])


@hsettings(200)
@given(name=st.sampled_from(sorted(VALID)), flips=st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)),
                                                            min_size=1, max_size=6))
def test_corrupted_bytes_give_only_particle_file_errors(tmp_path_factory, name, flips):
    """Random bytes overwritten anywhere (header or body): a ParticleFileError naming the file, or a valid set
    — of the declared 3 particles where the format declares a count; nothing else, no warning."""
    data = bytearray(VALID[name])
    for pos, byte in flips:
        data[int(pos * len(data))] = byte
    path = tmp_path_factory.mktemp("flip") / name
    path.write_bytes(bytes(data))
    try:
        p = _load(path)
    except ParticleFileError as exc:
        assert name in str(exc) and not FORBIDDEN.search(str(exc)), str(exc)
    else:
        assert np.all(np.isfinite(p.positions)) and np.all(p.radii_um > 0)
        if not name.endswith(".csv"):
            assert len(p) == 3


number = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10).map(float))


@hsettings(150)
@given(values=st.lists(st.tuples(number, number, number, number), min_size=1, max_size=4))
def test_csv_numbers_are_read_exactly_or_named(tmp_path_factory, values):
    """Any numbers in a CSV's columns: read exactly (repr round-trips) when coordinates are finite and radii
    finite and at least MIN_RADIUS_UM; else refused naming the first bad particle and field, as the module
    documents."""
    rows = np.array(values, dtype=np.float64)
    path = tmp_path_factory.mktemp("num") / "n.csv"
    path.write_bytes(csv(rows))
    bad_pos = np.argwhere(~np.isfinite(rows[:, :3]))
    bad_r = np.flatnonzero(~(np.isfinite(rows[:, 3]) & (rows[:, 3] >= MIN_RADIUS_UM)))
    if len(bad_pos):
        i, k = bad_pos[0]
        with pytest.raises(ParticleFileError, match=f"particle {i}: field {'xyz'[k]} is"):
            _load(path)
    elif len(bad_r):
        with pytest.raises(ParticleFileError, match=f"particle {bad_r[0]}: field radius is"):
            _load(path)
    else:
        p = _load(path)
        np.testing.assert_array_equal(np.column_stack([p.positions, p.radii_um]), rows)


@pytest.mark.parametrize("name", sorted(VALID))
def test_valid_files_read_exactly(tmp_path, name):
    """The files the property tests corrupt are read exactly when intact (a float PLY to float32)."""
    (tmp_path / name).write_bytes(VALID[name])
    p = _load(tmp_path / name)
    expect = ROWS.astype(np.float32) if name == "le.ply" else ROWS
    np.testing.assert_array_equal(np.column_stack([p.positions, p.radii_um]), expect)


def test_compressed_npz_reads_exactly(tmp_path):
    np.savez_compressed(tmp_path / "c.npz", positions=ROWS[:, :3], radii_um=ROWS[:, 3], species=np.arange(3, dtype=np.int32))
    p = _load(tmp_path / "c.npz")
    np.testing.assert_array_equal(np.column_stack([p.positions, p.radii_um]), ROWS)
    np.testing.assert_array_equal(p.species, [0, 1, 2])


def test_other_elements_are_skipped(tmp_path):
    """An ASCII PLY with a face element (list rows) after the vertices, and a binary one with a fixed-size
    element before them: the vertices are read, the counts still checked."""
    faces = b"element face 2\nproperty list uchar int vertex_indices\nend_header"
    a = ply().replace(b"end_header", faces) + b"3 0 1 2\n1 0\n"
    (tmp_path / "a.ply").write_bytes(a)
    np.testing.assert_array_equal(_load(tmp_path / "a.ply").radii_um, ROWS[:, 3])
    (tmp_path / "short.ply").write_bytes(a[:-len(b"1 0\n")])
    with pytest.raises(ParticleFileError, match="'face'.*declares 2 rows but the file holds 1"):
        _load(tmp_path / "short.ply")
    head = ("ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty float fov\n"
            "element vertex 3\nproperty double x\nproperty double y\nproperty double z\nproperty double radius\nend_header\n")
    (tmp_path / "b.ply").write_bytes(head.encode() + np.float32(40).byteswap().tobytes() + ROWS.astype(">f8").tobytes())
    np.testing.assert_array_equal(_load(tmp_path / "b.ply").positions, ROWS[:, :3])


if __name__ == "__main__":
    sys.exit(print(table()))
