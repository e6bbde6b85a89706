"""What ``motes render`` shows and writes, in one process (``motes.cli``) or from a Dask cluster
(``motes._distributed``): the progress bar, and the images (EXR, and a tone-mapped sRGB PNG beside it),
each written through a temporary file so that Ctrl-C never leaves a truncated one."""

from __future__ import annotations

import os
import pathlib
import sys

import numpy as np


def progress(done: int, total: int, elapsed: float, unit: str = "passes") -> None:
    """Redraw the progress bar on stderr: ``done`` of ``total`` ``unit`` after ``elapsed`` seconds, and the ETA."""
    width = 30
    filled = int(width * done / max(total, 1))
    eta = elapsed / done * (total - done) if done else float("nan")
    sys.stderr.write(f"\r  [{'#' * filled}{'.' * (width - filled)}] {done}/{total} {unit}  {elapsed:6.1f} s  ETA {eta:6.1f} s")
    sys.stderr.flush()


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


__all__ = ["exposure", "progress", "reinhard", "tonemap", "write_images"]
