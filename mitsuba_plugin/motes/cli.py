"""The ``motes`` command (also ``python -m motes``): render scenes, look at optics and particle files.

=====================================  ===================================================================
``motes render SCENE.xml``             render with Mitsuba (flags as ``mitsuba``'s: ``-o``, ``-m``, ``-D``,
                                       ``-s``) in passes with a progress bar; writes EXR (and ``--png``);
                                       ``--frames A:B`` a sequence ($frame, $time), ``--workers N`` /
                                       ``--scheduler ADDR`` on a Dask cluster (``motes.cluster``)
``motes optics``                       cross sections, efficiencies and g of one particle
``motes particles FILE``               summary of a particle file (count, bounds, radii, species, memory)
``motes equivalent``                   the homogeneous + tabphase XML of a particle cloud (A/B reference)
``motes scenes [-o DIR]``              the example scenes shipped in the package (list, or copy out)
``motes convert SCENE.xml -o OUT.xml`` a scene's homogeneous (and heterogeneous) media as ``discrete``, with a
                                       report of what could not be matched (``motes.convert``)
=====================================  ===================================================================

Errors print one line (``motes: error: ...``) and exit with status 2; ``--debug`` shows the traceback.
``motes render`` checks its options before it loads anything: ``-s``, ``--pass-spp``, ``--workers`` >= 1;
``--frames A:B[:STEP]`` (any length: frames are taken one at a time); ``-o`` an ``.exr`` name (none: ``.exr``
added), a folder (the default name inside it) or a pattern whose only field is ``{frame}`` with an integer
format (sequences only). Once the scene is loaded, the film's size is checked against Dr.Jit's array size
(2^32 values) and the memory available. Values Mitsuba's parser cannot read are shown with their element.
Ctrl-C during ``motes render`` stops within a second (loading, table builds and the kernel in flight
included), writes the passes done so far and exits with status 130.
"""

from __future__ import annotations

import argparse
import pathlib
import shutil
import signal
import re
import socket
import sys
import time
import warnings

import numpy as np

# exposure, reinhard and tonemap stay importable from here (motes.cli.tonemap: scripts/paper, tests).
from ._output import (check_film, check_writable, exposure, frames_summary, output_path, progress,  # noqa: F401
                      reinhard, tonemap, write_images)
from .convert import GRAIN_OPTIONS
from .cluster import (DEFAULT_FPS, frame_count, frame_defines, frame_output, parse_frames, pass_plan,
                      samples_per_pixel)


class _CtrlC:
    """Ctrl-C that ends ``motes render`` within a second whatever it is in. A Mitsuba kernel holds the GIL
    until it returns (seconds per pass) and a table build until its Rust call returns, so no Python code
    can react in time. SIGINT is routed through ``signal.set_wakeup_fd`` to a native thread
    (``_motes.exit_on_wakeup``) that prints the current message (``say``) and ends the process with
    status 130. The passes done so far are already on disk: they are written after each pass."""

    def __init__(self, message: str):
        self.message = message

    def say(self, message: str) -> None:
        from . import _motes  # noqa: PLC0415

        _motes.set_exit_message(message)

    def __enter__(self):
        from . import _motes  # noqa: PLC0415

        self._read, self._write = socket.socketpair()
        self._write.setblocking(False)
        self.say(self.message)
        _motes.exit_on_wakeup(self._read.fileno(), int(signal.SIGINT), 130)
        self._old_fd = signal.set_wakeup_fd(self._write.fileno(), warn_on_full_buffer=False)
        # The Python handler does nothing: the native thread ends the process.
        self._old_handler = signal.signal(signal.SIGINT, lambda *_: None)
        return self

    def __exit__(self, *exc):
        signal.signal(signal.SIGINT, self._old_handler)
        signal.set_wakeup_fd(self._old_fd)
        self._write.close()  # the native thread reads end-of-file and ends
        self._read.close()
        return False


def _show_load_stages() -> None:
    """Print the load stages the library logs at INFO (particles, optics tables, grid; with times)."""
    import logging  # noqa: PLC0415

    logger = logging.getLogger("motes")
    if not any(getattr(h, "_motes_cli", False) for h in logger.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("motes:   %(message)s"))
        handler._motes_cli = True
        logger.addHandler(handler)
    logger.setLevel(logging.INFO)


def shipped_scenes() -> dict[str, pathlib.Path]:
    """The example scenes in the package (``motes/scenes``), by stem."""
    folder = pathlib.Path(__file__).resolve().parent / "scenes"
    return {p.stem: p for p in sorted(folder.glob("*.xml"))}


def _scene_path(name: str) -> pathlib.Path:
    path = pathlib.Path(name)
    if path.is_file():
        return path
    shipped = shipped_scenes()
    stem = path.name.removesuffix(".xml")
    if path.parent == pathlib.Path(".") and stem in shipped:
        print(f"motes: {name} is not a file here; rendering the shipped scene {shipped[stem]}", file=sys.stderr)
        return shipped[stem]
    known = ", ".join(shipped) or "none"
    raise FileNotFoundError(f"no such scene file: {path} (shipped scenes, usable by name: {known})")


def _defines(pairs) -> dict:
    defines = {}
    for d in pairs:
        key, sep, value = d.partition("=")
        if not sep or not key:
            raise ValueError(f"-D expects key=value, got {d!r}")
        defines[key] = value
    return defines


def check_render_options(args) -> None:
    """``motes render``'s numbers and their combinations, before anything is loaded: ValueError naming the
    option (``-s 0`` is an error, not the scene's spp)."""
    for option, value in (("-s/--spp", args.spp), ("--pass-spp", args.pass_spp), ("--workers", args.workers)):
        if value is not None and value < 1:
            raise ValueError(f"{option} must be >= 1, got {value}")
    if args.fps is not None and not (np.isfinite(args.fps) and args.fps > 0):
        raise ValueError(f"--fps must be > 0, got {args.fps}")
    if args.workers is not None and args.scheduler:
        raise ValueError("give --workers (a local cluster) or --scheduler (an existing one), not both")
    if args.ship_files and not (args.workers or args.scheduler):
        raise ValueError("--ship-files sends files to cluster workers: it needs --workers or --scheduler")


def cmd_render(args) -> int:
    check_render_options(args)
    defines = _defines(args.define)
    scene_path = _scene_path(args.scene)
    frames = parse_frames(args.frames) if args.frames is not None else None
    # Where the (first) image goes, checked before minutes of loading: every later frame's name follows
    # the same checked pattern.
    out = output_path(args.output, scene_path.stem, frames[0] if frames is not None else None)
    check_writable(out)

    import motes  # noqa: PLC0415

    variant = motes.set_variant(args.variant)
    import mitsuba as mi  # noqa: PLC0415

    if args.workers or args.scheduler:
        from . import _distributed  # noqa: PLC0415

        return _distributed.render(args, mi, variant, scene_path, defines, frames)
    if frames is not None:
        return _render_frames(args, mi, variant, scene_path, defines, frames)
    _show_load_stages()
    with _CtrlC("motes: interrupted (Ctrl-C) before the first pass finished; nothing written") as ctrl_c:
        _render_one(args, mi, variant, scene_path, defines, out, ctrl_c)
    return 0


def _render_one(args, mi, variant, scene_path, defines, out, ctrl_c, quiet: bool = False) -> None:
    """One image in this process, pass by pass (``cluster.pass_plan``), each pass's average written at once
    (``quiet``, a frame of a sequence: written once, after its last pass, so that a frame on disk is a
    finished frame and a sequence resumed after Ctrl-C renders the interrupted one again)."""
    t0 = time.perf_counter()
    if not quiet:
        print(f"motes: loading {scene_path} ({variant}): particles, optics tables, grid ...", file=sys.stderr)
    scene = mi.load_file(str(scene_path), **defines)
    t_load = time.perf_counter() - t0
    if not quiet:
        print(f"motes: loaded in {t_load:.1f} s", file=sys.stderr)
    sensor = scene.sensors()[0]
    check_film(sensor.film(), defines)
    spp = samples_per_pixel(args.spp, sensor.sampler().sample_count())
    plan = pass_plan(spp, args.pass_spp, args.seed)
    acc, done_spp, t1 = None, 0, time.perf_counter()
    for i, (k, seed) in enumerate(plan):
        img = np.asarray(mi.render(scene, spp=k, seed=seed), dtype=np.float64)
        acc = img * k if acc is None else acc + img * k
        done_spp += k
        # Each pass's average is written at once, so that Ctrl-C keeps what is done.
        if not quiet or done_spp == spp:
            written = write_images(mi, out, (acc / done_spp).astype(np.float32), args.png)
        if done_spp < spp and not quiet:
            ctrl_c.say(f"motes: interrupted (Ctrl-C) after {done_spp} of {spp} spp; wrote {', '.join(written)}")
        if not quiet:
            progress(i + 1, len(plan), time.perf_counter() - t1)
    from ._memory import peak_resident_mb  # noqa: PLC0415

    if not quiet:
        sys.stderr.write("\n")
        print(f"motes: {spp} spp in {time.perf_counter() - t1:.1f} s (load {t_load:.1f} s), peak memory "
              f"{peak_resident_mb():.0f} MB; wrote {', '.join(written)}", file=sys.stderr)


def _render_frames(args, mi, variant, scene_path, defines, frames: range) -> int:
    """A frame sequence in this process: ``$frame`` and ``$time`` per frame; frames on disk are skipped.
    Frames are taken one at a time (a range of 10^9 frames starts at once)."""
    text = scene_path.read_text()
    total, skipped, done, shown = frame_count(frames), 0, 0, []  # shown: the first frames written
    t0 = time.perf_counter()
    with _CtrlC("motes: interrupted (Ctrl-C) before the first frame finished") as ctrl_c:
        for f in frames:
            out = frame_output(args.output, scene_path.stem, f)
            if not args.overwrite and out.exists():
                skipped += 1
                continue
            _render_one(args, mi, variant, scene_path, frame_defines(defines, f, args.fps or DEFAULT_FPS, text),
                        out, ctrl_c, quiet=True)
            done += 1
            shown += [out] * (len(shown) < 3)
            ctrl_c.say(f"motes: interrupted (Ctrl-C) after {done} frames, the last {out} (the frame in flight "
                       "is not written: a second run renders it)")
            progress(done, total - skipped, time.perf_counter() - t0, "frames")
    if done:
        sys.stderr.write("\n")
    frames_summary(done, skipped, total, time.perf_counter() - t0, shown)
    return 0


def _scene_title(path: pathlib.Path) -> str:
    """The first line of a scene's header comment (what it shows), without the comment marker."""
    text = path.read_text(errors="replace")
    start = text.find("<!--")
    if start < 0:
        return ""
    return text[start + 4:].strip().splitlines()[0].strip() if text[start + 4:].strip() else ""


def cmd_scenes(args) -> int:
    shipped = shipped_scenes()
    if args.output is None:
        for stem, path in shipped.items():
            print(f"{stem:12s} {_scene_title(path)}")
        print(f"\n(in {next(iter(shipped.values())).parent}; 'motes render NAME' renders one, "
              "'motes scenes -o DIR' copies them out)" if shipped else "no scenes shipped")
        return 0
    folder = pathlib.Path(args.output)
    folder.mkdir(parents=True, exist_ok=True)
    for path in shipped.values():
        shutil.copyfile(path, folder / path.name)
        print(f"wrote {folder / path.name}")
    return 0


def _index(args):
    import motes  # noqa: PLC0415

    if args.material:
        return motes.Material(args.material).index([args.wavelength])[0]
    try:
        return complex(args.eta.replace("i", "j").replace(" ", ""))
    except ValueError:
        raise ValueError(f"--eta must be a refractive index n or n+ki (e.g. 1.5+0.01i), got {args.eta!r}") from None


def cmd_optics(args) -> int:
    import motes  # noqa: PLC0415

    eta = _index(args)
    cs = motes.cross_sections([args.radius], args.wavelength, eta, eta_medium=args.eta_medium, method=args.method)
    area = np.pi * args.radius**2
    print(f"radius {args.radius:g} um, wavelength {args.wavelength:g} um, eta {eta.real:g}{eta.imag:+g}i, "
          f"medium {args.eta_medium:g}, method {args.method}")
    for key in ("ext", "sca", "abs"):
        v = float(np.asarray(cs[key])[0])
        print(f"  C_{key} = {v:.6g} um^2   Q_{key} = {v / area:.6g}")
    print(f"  g = {float(np.asarray(cs['g'])[0]):.6g}")
    return 0


def cmd_particles(args) -> int:
    import motes  # noqa: PLC0415

    ps = motes.load_particles(args.file, scale_m=args.scale_m)
    n = len(ps)
    lo, hi = ps.positions.min(axis=0), ps.positions.max(axis=0)
    q = np.percentile(ps.radii_um, [0, 1, 50, 99, 100])
    print(f"{args.file}: {n} particles")
    print(f"  bounds (scene units): min {lo.round(6).tolist()}  max {hi.round(6).tolist()}")
    print(f"  radius um: min {q[0]:.4g}  p1 {q[1]:.4g}  median {q[2]:.4g}  p99 {q[3]:.4g}  max {q[4]:.4g}")
    hist, edges = np.histogram(np.log10(ps.radii_um), bins=8)
    for c, a, b in zip(hist, edges[:-1], edges[1:]):
        print(f"    {10**a:9.4g} - {10**b:9.4g} um  {'#' * int(40 * c / max(hist.max(), 1)):40s} {c}")
    species, counts = np.unique(ps.species, return_counts=True)
    print("  species: " + ", ".join(f"{int(s)}: {int(c)}" for s, c in zip(species, counts)))
    # The grid a `discrete` medium would build from these particles (query_radius 0, default resolution;
    # the cross sections only scale optical depths, not the grid).
    grid = motes.ParticleGrid(ps.positions, ps.radii_um, 2.0 * np.pi * ps.radii_um**2, scale_m=args.scale_m)
    dims, nbytes = grid.dims, grid.bytes
    print(f"  grid of a discrete medium (query_radius 0): cells {' x '.join(map(str, dims))}, "
          f"{nbytes / 2**20:.1f} MiB ({nbytes / max(n, 1):.0f} bytes per particle)")
    return 0


def cmd_equivalent(args) -> int:
    import motes  # noqa: PLC0415

    species = motes.Species(motes.LogNormal(args.radius_median, args.radius_sigma_g),
                            motes.Material(args.material) if args.material else _index(args))
    d = motes.homogeneous_equivalent(species, args.density, scale_m=args.scale_m, tabphase_size=args.tabphase_size,
                                     polarized=args.polarized)
    from motes.equivalent import equivalent_xml  # noqa: PLC0415

    print(equivalent_xml(d, args.name))
    return 0


def cmd_convert(args) -> int:
    from .convert import convert_scene  # noqa: PLC0415

    grains = {name: getattr(args, name) for _, name, _, _ in GRAIN_OPTIONS if getattr(args, name) is not None}
    for pair in args.param:
        key, sep, value = pair.partition("=")
        if not sep:
            raise ValueError(f"--param {pair!r}: expected NAME=VALUE")
        grains[key.strip()] = value
    report = convert_scene(args.scene, args.output, medium=args.medium, grains=grains)
    print("\n".join(report))
    print(f"motes: wrote {args.output} (comments and everything else of the scene kept as they were)")
    return 0


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="motes", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--debug", action="store_true", help="show Python tracebacks")
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a Mitsuba XML scene in passes with progress")
    r.add_argument("scene", help="XML scene file, or the name of a shipped scene (see 'motes scenes')")
    r.add_argument("-o", "--output", help="output EXR (default: <scene stem>.exr; a folder: that name inside it; "
                   "no suffix: .exr added)")
    r.add_argument("-m", "--variant", default="llvm_ad_rgb", help="Mitsuba variant (default llvm_ad_rgb)")
    r.add_argument("-D", "--define", action="append", default=[], metavar="KEY=VALUE", help="scene parameter")
    r.add_argument("-s", "--spp", type=int, help="samples per pixel (default: the scene's)")
    r.add_argument("--pass-spp", type=int, default=8, help="samples per pass (bounds memory; default 8)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--png", action="store_true", help="also write a tone-mapped sRGB PNG beside the EXR")
    r.add_argument("--frames", metavar="A:B[:STEP]", help="render frames A..B (inclusive) with the scene parameters "
                   "$frame and $time = frame / fps; -o may hold {frame}, e.g. {frame:04d} (default out/NAME_0001.exr); "
                   "frames on disk are skipped")
    r.add_argument("--fps", type=float, help=f"frames per second for $time (default {DEFAULT_FPS:g})")
    r.add_argument("--overwrite", action="store_true", help="render frames again even if their file exists")
    r.add_argument("--workers", type=int, help="render on a local Dask cluster of this many worker processes")
    r.add_argument("--scheduler", metavar="ADDRESS", help="render on an existing Dask cluster (tcp://host:8786)")
    r.add_argument("--ship-files", action="store_true", help="send the scene and the files it names to the "
                   "workers (default: workers read them by path, from a shared file system)")
    r.set_defaults(run=cmd_render)
    sc = sub.add_parser("scenes", help="list the example scenes shipped with motes, or copy them out")
    sc.add_argument("-o", "--output", help="folder to copy the scenes to")
    sc.set_defaults(run=cmd_scenes)
    o = sub.add_parser("optics", help="cross sections and g of one particle")
    o.add_argument("--radius", type=float, required=True, help="um")
    o.add_argument("--wavelength", type=float, default=0.55, help="um (default 0.55)")
    o.add_argument("--eta", default="1.31", help="refractive index n or n+ki (default 1.31)")
    o.add_argument("--material", choices=["ice", "water"], help="tabulated index instead of --eta")
    o.add_argument("--eta-medium", type=float, default=1.0)
    o.add_argument("--method", default="auto", choices=["auto", "mie", "goa", "hybrid"])
    o.set_defaults(run=cmd_optics)
    p = sub.add_parser("particles", help="summary of a particle file (.npz, .npy, .csv, .ply)")
    p.add_argument("file")
    p.add_argument("--scale-m", type=float, default=1.0, help="metres per unit of the file's positions")
    p.set_defaults(run=cmd_particles)
    e = sub.add_parser("equivalent", help="homogeneous + tabphase XML of a log-normal particle cloud")
    e.add_argument("--radius-median", type=float, default=20.0, help="um")
    e.add_argument("--radius-sigma-g", type=float, default=1.5)
    e.add_argument("--eta", default="1.31")
    e.add_argument("--material", choices=["ice", "water"])
    e.add_argument("--wavelength", type=float, default=0.55, help=argparse.SUPPRESS)
    e.add_argument("--density", type=float, required=True, help="particles per m^3")
    e.add_argument("--scale-m", type=float, default=1.0, help="metres per scene unit")
    e.add_argument("--tabphase-size", type=int, default=4096)
    e.add_argument("--name", default="interior")
    e.add_argument("--polarized", action="store_true", help="phase motes_tabphase_polarized: the grains' Mueller "
                   "matrix in polarised variants (tabphase depolarises)")
    e.set_defaults(run=cmd_equivalent)
    c = sub.add_parser("convert", help="rewrite a scene's homogeneous (and heterogeneous) media as discrete, "
                       "with a report of what could not be matched")
    c.add_argument("scene", help="Mitsuba 3 XML scene")
    c.add_argument("-o", "--output", required=True, help="the converted scene (XML)")
    c.add_argument("--medium", metavar="ID", help="convert only the medium with this id (or name)")
    for option, name, tag, what in GRAIN_OPTIONS:
        c.add_argument(option, dest=name, metavar=tag.upper(), help=f"{what} ({name})")
    c.add_argument("-P", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="any other discrete parameter (count, footprint_k, fov, film_width, z_med, tau_max, ...)")
    c.set_defaults(run=cmd_convert)
    return ap


def one_line(e: BaseException) -> str:
    """An error as one line. Mitsuba's loader wraps a Python plugin's exception in a RuntimeError whose text
    holds the plugin's traceback: keep where (file, line) and what (the last line), drop the frames and the
    loader's source locations."""
    from ._errors import SOURCE_LOCATION, named_property, without_traceback  # noqa: PLC0415

    # Dr.Jit's "drjit.custom(...): error while performing a custom differentiable operation. (see above)"
    # says nothing: what it refers to is its cause.
    while e.__cause__ is not None and "(see above)" in str(e):
        e = e.__cause__
    text = str(e)
    head, sep, tail = text.partition("Traceback (most recent call last):")
    clean = without_traceback(text)
    if clean is not None:  # a user's error: the whole message, however many lines
        text = clean
    elif sep:
        last = [ln for ln in tail.strip().splitlines() if ln.strip()][-1]
        text = f"{head.strip()} {last.strip()}"
    text = named_property(SOURCE_LOCATION.sub("", text)).removeprefix("motes: ")
    return " ".join(text.split()) or type(e).__name__


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """Warnings on the command line as one line each: a user reads the message, not motes's source line."""
    text = str(message)
    return f"{text if text.startswith('motes:') else f'motes: {category.__name__}: {text}'}\n"


def _negative_frames_joined(argv: list[str]) -> list[str]:
    """``--frames -5:-1`` as ``--frames=-5:-1``: argparse reads a value that starts with '-' as an option."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--frames" and i + 1 < len(argv) and re.fullmatch(r"-\d+:-?\d+(:-?\d+)?", argv[i + 1]):
            out.append(f"--frames={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv=None) -> int:
    argv = _negative_frames_joined(list(sys.argv[1:] if argv is None else argv))
    args = parser().parse_args(argv)
    formatwarning, warnings.formatwarning = warnings.formatwarning, _one_line_warning
    try:
        return args.run(args)
    except KeyboardInterrupt:
        print("\nmotes: interrupted (Ctrl-C)", file=sys.stderr)
        return 130
    except (ValueError, RuntimeError, OSError, KeyError, MemoryError) as e:
        if args.debug:
            raise
        print(f"motes: error: {one_line(e)}", file=sys.stderr)
        return 2
    finally:
        warnings.formatwarning = formatwarning  # main() may be called in-process (tests, scripts)


if __name__ == "__main__":
    sys.exit(main())
