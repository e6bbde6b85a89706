"""Hostile input to ``motes render`` (issue 44, the command's part): output names and patterns, frame ranges,
sample counts, film sizes, scene files that are not XML and values Mitsuba's parser cannot read, each
through the command (in this process: ``main``) with the outcome it must get — a one-line error naming the
option or parameter (exit status 2, no traceback) or a documented behaviour (exit 0 and the file it writes)
— and words the message must hold. No row may crash, hang or render silently wrong.

    .venv/bin/python tests/test_hostile_cli.py     # prints the table of TESTING.md (runs every case)
"""

from __future__ import annotations

import contextlib
import io
import pathlib
import re
import sys
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

import motes
from motes import _output, cluster as C
from motes.cli import check_render_options, main, one_line, parser

mi = pytest.importorskip("mitsuba")

SCENE = """<scene version="3.0.0">
    <default name="spp" value="2"/>
    <default name="res" value="8"/>
    <integrator type="volpath"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>
    </sensor>
    <emitter type="constant"/>
    <shape type="cube">
        <bsdf type="null"/>
        <medium type="discrete" name="interior">
            <integer name="count" value="200"/>
            <float name="radius_median" value="300"/>
            <float name="scale_m" value="0.01"/>
            <phase type="particle"/>
        </medium>
    </shape>
</scene>
"""


@dataclass
class Case:
    """One input: ``argv`` after ``motes render SCENE -m scalar_rgb`` (``{tmp}`` is the case's folder), the
    scene's text with ``edit`` = (old, new) applied, or ``scene`` a file name that ``setup`` writes. ``rc``: the
    exit status; ``words``: what the message (the last line) must hold; ``writes``: the file (under ``{tmp}``)
    a documented behaviour writes."""

    name: str
    what: str
    argv: list[str]
    words: list[str]
    rc: int = 2
    edit: tuple[str, str] | None = None
    writes: str | None = None
    setup: object = field(default=None, repr=False)
    scene: str = "scene.xml"


def _set(old: str, new: str) -> tuple[str, str]:
    return (old, new)


CASES = [
    # -o patterns: only {frame}, with an integer format; checked before anything is loaded.
    Case("pattern_positional", "-o 'f_{frame}_{}.exr' (was an IndexError traceback)", ["--frames", "1:2", "-o", "f_{frame}_{}.exr"],
         ["-o", "{}", "{frame:04d}"]),
    Case("pattern_unknown_field", "-o 'f_{frame}_{name}.exr' (was `motes: error: 'name'`)",
         ["--frames", "1:2", "-o", "f_{frame}_{name}.exr"], ["-o", "{name}", "not a field"]),
    Case("pattern_bad_format", "-o 'f_{frame:q}.exr' (was a ValueError on the format)", ["--frames", "1:2", "-o", "f_{frame:q}.exr"],
         ["-o", "{frame:q}", "integer format"]),
    Case("pattern_float_format", "-o 'f_{frame:.2f}.exr'", ["--frames", "1:2", "-o", "f_{frame:.2f}.exr"], ["{frame:.2f}", "integer format"]),
    Case("pattern_conversion", "-o 'f_{frame!r}.exr'", ["--frames", "1:2", "-o", "f_{frame!r}.exr"], ["{frame!r}"]),
    Case("pattern_attribute", "-o 'f_{frame.real}.exr'", ["--frames", "1:2", "-o", "f_{frame.real}.exr"], ["{frame.real}"]),
    Case("pattern_lone_brace", "-o 'f_{frame.exr' (a lone brace)", ["--frames", "1:2", "-o", "f_{frame.exr"], ["-o", "{{"]),
    Case("pattern_too_wide", "-o 'f_{frame:0999999999d}.exr' (a 1 GB name)", ["--frames", "1:2", "-o", "f_{frame:0999999999d}.exr"],
         ["-o", "wider than 64"]),
    Case("pattern_without_frames", "-o 'f_{frame:04d}.exr' without --frames (was written literally)", ["-o", "f_{frame:04d}.exr"],
         ["{frame}", "--frames"]),
    Case("pattern_braces_escaped", "-o 'a{{b}}.exr' (escaped braces: a file a{b}.exr)", ["-o", "{tmp}/a{{b}}.exr"], [], rc=0,
         writes="a{b}.exr"),
    # Frame ranges: checked, then taken one at a time.
    Case("frames_empty", "--frames '' (rendered one image named f_{frame}.exr)", ["--frames", "", "-o", "f_{frame}.exr"],
         ["--frames", "A:B"]),
    Case("frames_reversed", "--frames 5:3", ["--frames", "5:3"], ["--frames", "A <= B"]),
    Case("frames_step_zero", "--frames 1:4:0", ["--frames", "1:4:0"], ["--frames", "STEP >= 1"]),
    Case("frames_words", "--frames one:two", ["--frames", "one:two"], ["--frames", "integers"]),
    # Samples and the other numbers.
    Case("spp_zero", "-s 0 (rendered the scene's spp)", ["-s", "0"], ["-s/--spp", ">= 1", "got 0"]),
    Case("spp_negative", "-s -3", ["-s", "-3"], ["-s/--spp", ">= 1"]),
    Case("pass_spp_zero", "--pass-spp 0", ["--pass-spp", "0"], ["--pass-spp", ">= 1"]),
    Case("workers_zero", "--workers 0", ["--workers", "0"], ["--workers", ">= 1"]),
    Case("fps_nan", "--fps nan", ["--frames", "1", "--fps", "nan"], ["--fps", "> 0"]),
    Case("scene_spp_zero", "-D spp=0 (the scene's sample_count 0)", ["-D", "spp=0"], ["sample_count 0", "-s N"]),
    # Where images go.
    Case("output_png", "-o out.png (was a Bitmap 'component type' error after the render)", ["-o", "out.png"],
         ["-o", ".exr", "--png"]),
    Case("output_other_suffix", "-o out.tiff", ["-o", "out.tiff"], ["-o", ".exr", ".tiff"]),
    Case("output_empty", "-o ''", ["-o", ""], ["-o is empty"]),
    Case("output_under_a_file", "-o SCENE.xml/x.exr (a folder that is a file)", ["-o", "{tmp}/scene.xml/x.exr"],
         ["-o", "is a file, not a folder"]),
    Case("output_name_too_long", "-o with a 300-character name", ["-o", "{tmp}/" + "a" * 300 + ".exr"], ["-o", "255 bytes"]),
    Case("output_folder", "-o an existing folder (was a Bitmap '.partial' error): the default name in it", ["-o", "{tmp}"],
         [], rc=0, writes="scene.exr"),
    Case("output_new_folder", "-o 'new/' (a name ending in /): made, the default name in it", ["-o", "{tmp}/new/"], [], rc=0,
         writes="new/scene.exr"),
    Case("output_no_suffix", "-o 'img' (no suffix): img.exr", ["-o", "{tmp}/img"], [], rc=0, writes="img.exr"),
    # The film.
    Case("film_too_large", "-D res=100000 (was `drjit.custom(...) (see above)`)", ["-D", "res=100000"],
         ["film of 100000 x 100000 pixels", "-D res=100000", "2^32", "width and height"]),
    Case("film_empty", "-D res=0 (was `Invalid display window in image header`)", ["-D", "res=0"], ["-D res=0", "no pixels"]),
    Case("film_negative", "-D res=-5 (a `[properties.h:868]` prefix leaked)", ["-D", "res=-5"], ['"height"', "out of bounds"]),
    # Scene files and values Mitsuba's parser cannot read: the element, so the property's name.
    Case("integer_as_float", '<integer name="count" value="1e6"/>', [], ['name="count"', 'value="1000000"'],
         edit=_set('<integer name="count" value="200"/>', '<integer name="count" value="1e6"/>')),
    Case("integer_fraction", '<integer name="count" value="5.5"/>', [], ['name="count"', "whole number", "<float>"],
         edit=_set('<integer name="count" value="200"/>', '<integer name="count" value="5.5"/>')),
    Case("integer_overflow", '<integer name="count" value="99999999999999999999"/>', [], ['name="count"', "2^63"],
         edit=_set('<integer name="count" value="200"/>', '<integer name="count" value="99999999999999999999"/>')),
    Case("float_text", '<float name="radius_median" value="abc"/>', [], ['name="radius_median"', "<float>"],
         edit=_set('value="300"', 'value="abc"')),
    Case("float_comma", '<float name="radius_median" value="0,5"/>', [], ['name="radius_median"', "decimal point"],
         edit=_set('value="300"', 'value="0,5"')),
    Case("define_not_integer", "-D spp=many", ["-D", "spp=many"], ['name="sample_count"', 'value="$spp"', '"many"']),
    Case("define_not_integer_workers", "--workers 1 -D spp=many (was `invalid literal for int()`)",
         ["--workers", "1", "-D", "spp=many"], ['name="sample_count"', '"many"']),
    Case("not_xml_workers", "--workers 1 on a file that is not XML (was an XML ParseError traceback)", ["--workers", "1"],
         ["Parsing of XML file", "notes.txt"], scene="notes.txt", setup=lambda d: (d / "notes.txt").write_text("not xml\n")),
    Case("not_xml", "a file that is not XML", [], ["Parsing of XML file", "notes.txt"], scene="notes.txt",
         setup=lambda d: (d / "notes.txt").write_text("not xml\n")),
]


def run_case(case: Case, tmp: pathlib.Path) -> tuple[int, str]:
    """(exit status, message: what the command printed, less its progress lines) of one case."""
    (tmp / "scene.xml").write_text(SCENE.replace(*case.edit) if case.edit else SCENE)
    if case.setup:
        case.setup(tmp)
    argv = ["render", str(tmp / case.scene), "-m", "scalar_rgb", *(a.replace("{tmp}", str(tmp)) for a in case.argv)]
    if "-o" not in case.argv and "--frames" not in case.argv:
        argv += ["-o", str(tmp / "out.exr")]
    err = io.StringIO()
    with contextlib.chdir(tmp), contextlib.redirect_stderr(err):
        rc = main(argv)
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip() and not ln.startswith(("motes: load", "motes:   ", "  ["))]
    return rc, "\n".join(lines)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_hostile_input(case: Case, tmp_path):
    rc, msg = run_case(case, tmp_path)
    assert rc == case.rc, msg
    assert "Traceback" not in msg and not re.search(r"\[[\w.]+\.(?:h|cpp):\d+\]", msg), msg
    if case.rc == 2:
        assert msg.startswith("motes: error: ") and "\n" not in msg, msg
        assert all(w in msg for w in case.words), msg
        assert not any((tmp_path / n).exists() for n in ("out.exr", "f_{frame}.exr", "f_{frame:04d}.exr")), msg
    if case.writes:
        assert (tmp_path / case.writes).is_file(), msg


@given(spp=st.one_of(st.none(), st.integers(-10**12, 10**12)), pass_spp=st.integers(-10**12, 10**12),
       workers=st.one_of(st.none(), st.integers(-10**6, 10**6)))
def test_counts_below_one_are_errors_naming_the_option(spp, pass_spp, workers):
    """-s, --pass-spp and --workers: >= 1, else a ValueError naming the first bad one (never a fallback)."""
    args = parser().parse_args(["render", "s.xml", "--pass-spp", str(pass_spp)]
                               + (["-s", str(spp)] if spp is not None else [])
                               + (["--workers", str(workers)] if workers is not None else []))
    bad = [o for o, v in (("-s/--spp", spp), ("--pass-spp", pass_spp), ("--workers", workers)) if v is not None and v < 1]
    if bad:
        with pytest.raises(ValueError, match=bad[0]):
            check_render_options(args)
    else:
        check_render_options(args)
        assert C.samples_per_pixel(spp, 4) == (spp if spp is not None else 4)


@given(a=st.integers(-10**20, 10**20), n=st.integers(0, 10**20), step=st.integers(1, 10**6))
def test_frame_ranges_are_lazy_and_exact(a, n, step):
    """Any range parses at once (a range object, nothing expanded) to the frames A, A + STEP, ... <= B."""
    b = a + n
    frames = C.parse_frames(f"{a}:{b}:{step}")
    assert isinstance(frames, range) and frames[0] == a and frames[-1] <= b < frames[-1] + step
    assert C.frame_count(frames) == n // step + 1
    if n < 50:
        assert list(frames) == list(range(a, b + 1, step))


@given(frame=st.integers(-10**6, 10**9), width=st.integers(0, 64), zero=st.booleans())
def test_frame_names_follow_the_pattern(frame, width, zero):
    """Every integer format names each frame by its number, and distinct frames by distinct files."""
    spec = f"{'0' if zero else ''}{width or ''}d"
    path = C.frame_output(f"out/f_{{frame:{spec}}}.exr", "s", frame)
    assert path == pathlib.Path(f"out/f_{frame:{spec}}.exr")
    assert C.frame_output(f"out/f_{{frame:{spec}}}.exr", "s", frame + 1) != path


def test_a_billion_frames_start_at_once(tmp_path, monkeypatch):
    """--frames 1:1000000000 used to build its frame list first (4 GB, 20 s, no output): frames now come one
    at a time; the third frame's render is interrupted (Ctrl-C), two are written."""
    from motes import cli

    (tmp_path / "scene.xml").write_text(SCENE)
    done = []

    def render_one(args, mi, variant, scene_path, defines, out, ctrl_c, quiet=False):
        if len(done) == 2:
            raise KeyboardInterrupt
        out.write_bytes(b"frame")
        done.append(out.name)

    monkeypatch.setattr(cli, "_render_one", render_one)
    t0 = time.perf_counter()
    with contextlib.redirect_stderr(io.StringIO()):
        rc = main(["render", str(tmp_path / "scene.xml"), "-m", "scalar_rgb", "--frames", "1:1000000000",
                   "-o", str(tmp_path / "f_{frame:010d}.exr")])
    assert rc == 130 and done == ["f_0000000001.exr", "f_0000000002.exr"]
    assert time.perf_counter() - t0 < 10


def test_cluster_frames_are_submitted_as_asked(tmp_path):
    """On a cluster, frames are submitted one at a time as the client asks (a window of them in flight), the
    ones on disk skipped, whatever the range's length."""
    from motes import _distributed

    (tmp_path / "scene.xml").write_text(SCENE)
    (tmp_path / "f_2.exr").write_bytes(b"on disk")
    submitted = []
    client = SimpleNamespace(submit=lambda *a, key, pure: submitted.append(key) or key)
    args = SimpleNamespace(fps=None, overwrite=False, output=str(tmp_path / "f_{frame}.exr"), ship_files=False)
    frames = _distributed._submit_frames(client, args, "scalar_rgb", tmp_path / "scene.xml", {}, C.parse_frames("1:1000000000"), [])
    assert [(f, fut is not None) for f, fut in (next(frames) for _ in range(3))] == [(1, True), (2, False), (3, True)]
    assert len(submitted) == 2


def test_film_larger_than_memory_names_its_size(monkeypatch):
    """A film that fits Dr.Jit's arrays but not the memory available: MemoryError naming its size and -D."""
    motes.set_variant("scalar_rgb")
    film = mi.load_dict({"type": "hdrfilm", "width": 10000, "height": 10000})
    monkeypatch.setattr(motes._memory, "available", lambda: (2**30, "(a test)"))
    with pytest.raises(MemoryError, match=r"10000 x 10000 pixels \(-D res=10000\).*GiB"):
        _output.check_film(film, {"res": "10000", "spp": "4"})
    monkeypatch.setattr(motes._memory, "available", lambda: (2**40, "(a test)"))
    _output.check_film(film, {"res": "10000"})


def test_an_error_that_says_see_above_is_its_cause():
    """Dr.Jit's ``drjit.custom(...) ... (see above)``: the line is what it refers to, its cause."""
    try:
        try:
            raise RuntimeError("Tensor(): invalid size specified (40000000000 vs 1345294336)!")
        except RuntimeError as inner:
            raise RuntimeError("drjit.custom(<_RenderOp>): error while performing a custom differentiable "
                               "operation. (see above).") from inner
    except RuntimeError as e:
        assert one_line(e) == "Tensor(): invalid size specified (40000000000 vs 1345294336)!"


def test_worker_tracebacks_stay_out_of_the_one_line(tmp_path, capfd):
    """A scene a worker cannot load (count = 0) on a local cluster: one line, none of Dask's "Compute
    Failed" logs or the worker's traceback before it (they print with --debug)."""
    pytest.importorskip("distributed")
    scene = tmp_path / "scene.xml"
    scene.write_text(SCENE.replace('<integer name="count" value="200"/>', '<integer name="count" value="0"/>'))
    assert main(["render", str(scene), "-m", "scalar_rgb", "--workers", "1", "-o", str(tmp_path / "o.exr")]) == 2
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Compute Failed" not in err, err
    assert [ln for ln in err.splitlines() if ln.startswith("motes: error:")][0].count("count = 0") == 1, err


def table() -> str:
    import tempfile

    rows = ["| # | input | outcome | message |", "|---|---|---|---|"]
    for i, case in enumerate(CASES, 1):
        with tempfile.TemporaryDirectory() as d:
            rc, msg = run_case(case, pathlib.Path(d))
        msg = msg.replace(d, "<tmp>").replace("\n", " ").replace("|", "\\|")
        outcome = f"exit {rc}" + (f", writes {case.writes}" if case.writes else "")
        rows.append(f"| {i} | {case.what.replace('|', chr(92) + '|')} | {outcome} | {msg} |")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(print(table()))


@pytest.mark.parametrize("spec", ["-5:-1", "-5:3", "-10:-2:4", "-3:-3"])
def test_negative_frame_ranges_need_no_equals_sign(spec):
    """``--frames -5:-1`` (argparse reads a value starting with '-' as an option: it needed ``--frames=-5:-1``)."""
    from motes.cli import _negative_frames_joined

    argv = _negative_frames_joined(["render", "scene.xml", "--frames", spec, "-s", "1"])
    args = parser().parse_args(argv)
    assert args.frames == spec and args.spp == 1
    frames = C.parse_frames(args.frames)
    assert frames[0] == int(spec.split(":")[0])


def test_a_cuda_variant_without_a_gpu_is_one_line(tmp_path):
    """Issue 46: ``-m cuda_ad_rgb`` where Dr.Jit finds no CUDA driver: one line naming the variant and the CPU's
    instead (it was an ImportError's traceback), exit status 2, nothing written."""
    import drjit as dr

    if "cuda_ad_rgb" not in mi.variants():
        pytest.skip("Mitsuba has no cuda_ad_rgb variant here")
    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("a GPU is here: cuda_ad_rgb runs")
    (tmp_path / "scene.xml").write_text(SCENE)
    before = mi.variant()
    err = io.StringIO()
    try:
        with contextlib.chdir(tmp_path), contextlib.redirect_stderr(err):
            rc = main(["render", str(tmp_path / "scene.xml"), "-m", "cuda_ad_rgb", "-o", str(tmp_path / "out.exr")])
    finally:
        if before:
            mi.set_variant(before)
    msg = err.getvalue().strip()
    assert rc == 2, msg
    assert msg.startswith("motes: error: ") and "\n" not in msg and "Traceback" not in msg, msg
    assert all(w in msg for w in ("cuda_ad_rgb", "NVIDIA GPU", "llvm_ad_rgb")), msg
    assert not (tmp_path / "out.exr").exists()
