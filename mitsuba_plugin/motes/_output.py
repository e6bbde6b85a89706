"""What ``motes render`` shows and writes, in one process (``motes.cli``) or from a Dask cluster
(``motes._distributed``): the progress bar, and the images (EXR, and a tone-mapped sRGB PNG beside it),
each written through a temporary file so that Ctrl-C never leaves a truncated one.

Where images go (``output_path``, checked before anything is loaded) and whether the film fits
(``check_film``, checked once the scene is loaded, before the first pass) are decided here, once for
the single-process and the cluster renders."""

from __future__ import annotations

import os
import pathlib
import re
import string
import sys

import numpy as np

#: The file type ``motes render`` writes: OpenEXR (linear, float). ``--png`` adds a tone-mapped PNG beside it.
SUFFIX = ".exr"
#: A ``{frame}`` field's format: an integer one (fill, alignment, sign, zero padding, width, grouping, ``d``).
_FRAME_SPEC = re.compile(r"(?:[^{}]?[<>=^])?[+\- ]?#?(?P<zero>0?)(?P<width>\d*)[,_]?d?")
#: The widest ``{frame}`` field (a file name holds at most 255 bytes on common file systems).
_MAX_WIDTH = 64
#: Values in one Dr.Jit array (its sizes are 32-bit): a film's pixels times its channels must stay below.
ARRAY_LIMIT = 2**32 - 1
#: Bytes per pixel and channel of a render, beyond the scene: the film's float32 block and developed image,
#: the float64 pass image and running sum of ``motes render``, and the float32 copy written.
FILM_BYTES_PER_VALUE = 4 + 4 + 8 + 8 + 4


def progress(done: int, total: int, elapsed: float, unit: str = "passes") -> None:
    """Redraw the progress bar on stderr: ``done`` of ``total`` ``unit`` after ``elapsed`` seconds, and the ETA."""
    width = 30
    filled = int(width * done / max(total, 1))
    eta = elapsed / done * (total - done) if done else float("nan")
    sys.stderr.write(f"\r  [{'#' * filled}{'.' * (width - filled)}] {done}/{total} {unit}  {elapsed:6.1f} s  ETA {eta:6.1f} s")
    sys.stderr.flush()


def frames_summary(done: int, skipped: int, total: int, seconds: float, shown, where: str = "") -> None:
    """The last lines of a sequence: what was on disk already, and what was rendered (``shown``: the first
    files written)."""
    if skipped:
        print(f"motes: {skipped} of {total} frames already on disk, skipped (--overwrite renders them again)",
              file=sys.stderr)
    names = f" ({', '.join(map(str, shown))}{' ...' if done > len(shown) else ''})" if shown else ""
    print(f"motes: {done} frames in {seconds:.1f} s{where}{names}", file=sys.stderr)


# Rec. 709 luminance of linear RGB.
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def exposure(img: np.ndarray, key: float = 0.18, white_percentile: float = 99.5) -> tuple[float, float]:
    """(log-average luminance, white point) of ``tonemap``'s operator for ``img``: applied to other images
    with ``reinhard``, one exposure for several pictures (a contact sheet)."""
    rgb = np.clip(np.nan_to_num(np.asarray(img, dtype=np.float64), nan=0.0, posinf=0.0), 0.0, None)
    lum = rgb[..., :3] @ _LUMINANCE if rgb.shape[-1] >= 3 else rgb[..., 0]
    log_avg = float(np.exp(np.mean(np.log(1e-6 + lum))))
    white = max(float(np.percentile(lum * (key / max(log_avg, 1e-12)), white_percentile)), 1e-6)
    return log_avg, white


def reinhard(img: np.ndarray, log_avg: float, white: float, key: float = 0.18) -> np.ndarray:
    """Reinhard's global operator with a given exposure: linear RGB to display values in [0, 1]."""
    rgb = np.clip(np.nan_to_num(np.asarray(img, dtype=np.float64), nan=0.0, posinf=0.0), 0.0, None)
    lum = rgb[..., :3] @ _LUMINANCE if rgb.shape[-1] >= 3 else rgb[..., 0]
    scaled = lum * (key / max(log_avg, 1e-12))
    display = scaled * (1.0 + scaled / white**2) / (1.0 + scaled)
    gain = np.divide(display, lum, out=np.zeros_like(lum), where=lum > 0)
    return np.clip(rgb * gain[..., None], 0.0, 1.0)


def tonemap(img: np.ndarray, key: float = 0.18, white_percentile: float = 99.5) -> np.ndarray:
    """Linear RGB (H, W, C) to display values in [0, 1]: Reinhard et al.'s global photographic operator.
    The log-average luminance maps to ``key`` (mid grey) and the ``white_percentile``-th luminance to
    white; brighter pixels (a floor patch lit by a spot) saturate smoothly instead of setting the
    exposure of the whole picture, so a dim room stays readable beside a bright beam."""
    return reinhard(img, *exposure(img, key, white_percentile), key=key)


def _write_atomically(path: pathlib.Path, write) -> None:
    """Write through a temporary file and rename, so that Ctrl-C never leaves a truncated image."""
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    write(str(tmp))
    os.replace(tmp, path)


def _frame_fields(pattern: str) -> bool:
    """Whether ``-o``'s ``pattern`` holds ``{frame}`` fields; ValueError naming ``-o`` for any other field
    (``{}``, ``{name}``, ``{frame!r}``, ``{frame.real}``), a format that is not an integer one (``{frame:q}``,
    ``{frame:.2f}``) or a lone brace."""
    fix = "the only field is {frame}, with an integer format such as {frame:04d}; {{ and }} write braces"
    try:
        fields = [(name, conv, spec) for _, name, spec, conv in string.Formatter().parse(pattern) if name is not None]
    except ValueError as e:  # "Single '}' encountered in format string"
        raise ValueError(f"-o {pattern!r}: {e} ({fix})") from None
    for name, conv, spec in fields:
        field = "{" + name + (f"!{conv}" if conv else "") + (f":{spec}" if spec else "") + "}"
        if name != "frame" or conv:
            raise ValueError(f"-o {pattern!r}: {field} is not a field motes fills in ({fix})")
        m = _FRAME_SPEC.fullmatch(spec or "")
        if m is None:
            raise ValueError(f"-o {pattern!r}: {field} is not an integer format ({fix})")
        if m["width"] and int(m["width"]) > _MAX_WIDTH:
            raise ValueError(f"-o {pattern!r}: {field} is wider than {_MAX_WIDTH} characters")
    return bool(fields)


def output_path(pattern: str | None, stem: str, frame: int | None = None) -> pathlib.Path:
    """Where ``motes render`` writes its image (``frame`` None) or frame ``frame`` of a sequence, from ``-o``
    (``pattern``) and the scene's file name (``stem``); ValueError naming ``-o`` where it cannot be used.

    * No ``-o``: ``STEM.exr``; a sequence's frames ``out/STEM_0001.exr``, ...
    * A folder (one that exists, or a name ending in ``/``): that default file name inside it.
    * ``-o`` is a format pattern: ``{frame}`` (an integer format allowed: ``{frame:05d}``) is the frame
      number, ``{{`` and ``}}`` are braces, any other field is an error. Only a sequence has a frame
      number: ``{frame}`` without ``--frames`` is an error (``--frames N`` renders frame N alone). A
      sequence's pattern without ``{frame}`` gets ``_0001`` before its suffix.
    * The file is an OpenEXR image: suffix ``.exr`` (any case); a name without a suffix gets it; any other
      suffix is an error (``--png`` writes a tone-mapped PNG beside the EXR)."""
    default = f"{stem}.exr" if frame is None else f"{stem}_{frame:04d}.exr"
    if pattern is None:
        return pathlib.Path(default) if frame is None else pathlib.Path("out") / default
    if not pattern.strip():
        raise ValueError("-o is empty: give an .exr file name or a folder")
    if _frame_fields(pattern) and frame is None:
        raise ValueError(f"-o {pattern!r} holds {{frame}}, the frame number of a sequence: add --frames "
                         "(--frames N renders frame N alone) or leave {frame} out")
    name = pattern.format(frame=frame)
    p = pathlib.Path(name)
    if name.endswith(("/", os.sep)) or os.path.isdir(name):
        return p / default
    if frame is not None and "{frame" not in pattern:
        p = p.with_name(f"{p.stem}_{frame:04d}{p.suffix}")
    if not p.suffix:
        return p.with_name(p.name + SUFFIX)
    if p.suffix.lower() != SUFFIX:
        png = p.suffix.lower() in (".png", ".jpg", ".jpeg")
        hint = " (add --png for a tone-mapped PNG beside the EXR)" if png else ""
        raise ValueError(f"-o {pattern!r}: motes render writes OpenEXR images, {SUFFIX}, not {p.suffix}{hint}")
    return p


def check_writable(path: pathlib.Path) -> None:
    """ValueError naming ``-o`` where ``path`` cannot be written: its folder (made when missing) lies under a
    file or in a folder this process may not write, or a name is longer than the file system takes."""
    folder = path.parent
    existing = next((p for p in (folder, *folder.parents) if os.path.exists(p)), pathlib.Path("."))
    if not existing.is_dir():
        raise ValueError(f"-o {str(path)!r}: {str(existing)!r} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"-o {str(path)!r}: no permission to write in the folder {str(existing)!r}")
    try:
        longest = os.pathconf(existing, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        longest = 255
    for part in path.relative_to(existing).parts:
        if len(os.fsencode(part)) > longest:
            raise ValueError(f"-o {str(path)!r}: the name {part[:20]!r}... is longer than the {longest} bytes "
                             "a file name may have here")


def check_film(film, defines: dict) -> None:
    """Before the first pass: a film with no pixels, more values than one Dr.Jit array holds (Dr.Jit's
    ``drjit.custom(...) (see above)`` mid-render otherwise) or larger than the memory available is an error
    naming its size and the ``-D`` parameters that set it (``-D res=100000``)."""
    from ._memory import require  # noqa: PLC0415

    width, height = (int(v) for v in film.crop_size())
    # The film's block holds its channels and a weight (a developed RGB image: 4 values a pixel).
    channels = int(film.base_channels_count()) + 1
    given = ", ".join(f"-D {k}={v}" for k, v in defines.items() if str(v).strip() in (str(width), str(height)))
    what = f"the film of {width} x {height} pixels" + (f" ({given})" if given else "")
    if width < 1 or height < 1:
        raise ValueError(f"{what} has no pixels: its width and height must be >= 1")
    values = width * height * channels
    if values > ARRAY_LIMIT:
        side = int((ARRAY_LIMIT / channels) ** 0.5)
        raise ValueError(f"{what} holds {values:.3g} values ({channels} a pixel), more than the 2^32 of one "
                         f"Dr.Jit array: at most about {side} x {side} pixels; lower the film's width and height")
    require(values * FILM_BYTES_PER_VALUE, what)


def write_images(mi, exr: pathlib.Path, img: np.ndarray, png: bool) -> list[str]:
    """The EXR (linear) and, if asked, a tone-mapped sRGB PNG beside it."""
    exr.parent.mkdir(parents=True, exist_ok=True)
    _write_atomically(exr, mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32)).write)
    written = [str(exr)]
    if png:
        path = exr.with_suffix(".png")
        bmp = mi.Bitmap(np.ascontiguousarray(tonemap(img), dtype=np.float32))
        fmt = mi.Bitmap.PixelFormat.RGB if img.shape[-1] >= 3 else mi.Bitmap.PixelFormat.Y
        _write_atomically(path, bmp.convert(fmt, mi.Struct.Type.UInt8, srgb_gamma=True).write)
        written.append(str(path))
    return written


__all__ = ["ARRAY_LIMIT", "SUFFIX", "check_film", "check_writable", "exposure", "frames_summary", "output_path",
           "progress", "reinhard", "tonemap", "write_images"]
