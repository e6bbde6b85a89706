"""Shared helpers of the figure-reproduction and benchmark scripts in ``scripts/figures/`` and
``scripts/bench/``.

Not a script: imported by every script there but ``scripts/figures/furnace_grid.py`` (they put
``scripts/``, the folder of this module, on ``sys.path`` because they are run as files).

Conventions (the paper's, Guo et al., Sec. 3.3 and App. E):

* ``LAM = 0.6`` um, ``THETA = np.linspace(0, pi, 1800)``;
* RelMSE of amplitudes: ``mean_theta[(G - M)^2] / mean_theta[M^2]`` with ``G, M = (|S1| + |S2|)/2`` of
  GOA and Mie (:func:`relmse`, :func:`amp_mean`);
* RelMSE of the extinction cross section: ``(C3 - C1)^2 / C3^2`` (Eq. 38, :func:`relmse_scalar`).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import pathlib
import platform
import subprocess
import sys
import time
from typing import Any, Callable, Iterable, Sequence

import numpy as np

LAM = 0.6
THETA = np.linspace(0.0, np.pi, 1800)
ROOT = pathlib.Path(__file__).resolve().parent.parent


def import_motes(retries: int = 5, wait_s: float = 60.0):
    """Import ``motes``; the Rust extension may be briefly missing while it is rebuilt, so retry."""
    for attempt in range(retries + 1):
        try:
            import motes  # noqa: PLC0415

            return motes
        except ImportError as exc:  # pragma: no cover - only while the extension is rebuilt
            if attempt == retries:
                raise
            print(f"[import motes failed: {exc}; retrying in {wait_s:.0f} s]", file=sys.stderr)
            for name in [m for m in sys.modules if m == "motes" or m.startswith("motes.")]:
                del sys.modules[name]
            time.sleep(wait_s)
    raise RuntimeError("unreachable")


def choose_configs(ap: argparse.ArgumentParser, text: str, known) -> list[str]:
    """The comma-separated configuration names of a ``--configs`` flag, each checked against ``known``."""
    configs = [c.strip() for c in text.split(",") if c.strip()]
    for c in configs:
        if c not in known:
            ap.error(f"unknown configuration {c!r}; choose from {list(known)}")
    return configs


def start(doc: str | None):
    """The common start of a script: parsed ``--out/--quick`` arguments, the output folder, a stopwatch
    and the imported ``motes``."""
    args = parser(doc).parse_args()
    return args, out_dir(args.out), Stopwatch(), import_motes()


def plt():
    """``matplotlib.pyplot`` on the Agg backend."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as _plt  # noqa: PLC0415

    _plt.rcParams.update({"figure.dpi": 110, "savefig.dpi": 110, "font.size": 9})
    return _plt


def parser(doc: str | None) -> argparse.ArgumentParser:
    """Argument parser with the two options every script has: ``--out`` and ``--quick``."""
    ap = argparse.ArgumentParser(description=(doc or "").split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/", help="output folder for PNGs and JSON (default: out/)")
    ap.add_argument("--quick", action="store_true", help="reduced run (fewer points / repetitions)")
    return ap


def out_dir(path: str) -> pathlib.Path:
    p = pathlib.Path(path)
    p.mkdir(parents=True, exist_ok=True)
    return p


# --------------------------------------------------------------------------------------------- metrics
def amp_mean(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """``(|S1| + |S2|)/2``."""
    return 0.5 * (np.abs(s1) + np.abs(s2))


def relmse(g: np.ndarray, m: np.ndarray) -> float:
    """``mean[(G - M)^2] / mean[M^2]`` over the last axis (the angles)."""
    g = np.asarray(g, dtype=float)
    m = np.asarray(m, dtype=float)
    return float(np.mean((g - m) ** 2) / np.mean(m**2))


def relmse_scalar(c_ref, c) -> np.ndarray:
    """Eq. 38: ``(C_ref - C)^2 / C_ref^2`` (elementwise)."""
    c_ref = np.asarray(c_ref, dtype=float)
    c = np.asarray(c, dtype=float)
    return (c_ref - c) ** 2 / c_ref**2


def radius_of_x(x, lam: float = LAM):
    """Radius (um) of size parameter ``x = 2 pi r / lam`` in vacuum/air."""
    return np.asarray(x, dtype=float) * lam / (2.0 * np.pi)


# ---------------------------------------------------------------------------------------------- timing
def best_of(fn: Callable[[], Any], n: int = 3) -> tuple[float, Any]:
    """Best wall time (s, ``time.perf_counter``) of ``n`` calls of ``fn`` and the last result."""
    best = math.inf
    result = None
    for _ in range(max(1, n)):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


class Stopwatch:
    """Wall time since construction."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()

    def __call__(self) -> float:
        return time.perf_counter() - self.t0


# ---------------------------------------------------------------------------------------------- output
def fmt(v, digits: int = 3) -> str:
    """Compact number formatting for tables."""
    if v is None:
        return "—"
    if isinstance(v, str):
        return v
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    v = float(v)
    if not math.isfinite(v):
        return str(v)
    if v == 0.0:
        return "0"
    a = abs(v)
    if v == round(v) and a < 1e6:
        return str(int(round(v)))
    if 1e-3 <= a < 1e5:
        s = f"{v:.{digits}g}"
    else:
        s = f"{v:.{max(digits - 1, 1)}e}"
    return s


def md_table(headers: Sequence[str], rows: Iterable[Sequence[Any]], digits: int = 3) -> str:
    """A GitHub Markdown table."""
    esc = lambda t: str(t).replace("|", "\\|")  # noqa: E731  (pipes inside cells, e.g. |S1|)
    rows = [[esc(fmt(c, digits)) for c in r] for r in rows]
    headers = [esc(h) for h in headers]
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def print_table(title: str, headers: Sequence[str], rows: Iterable[Sequence[Any]], digits: int = 3) -> str:
    s = md_table(headers, rows, digits)
    print(f"\n**{title}**\n\n{s}\n")
    return s


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.bool_, bool)):
        return bool(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating, float)):
        f = float(o)
        return f if math.isfinite(f) else str(f)
    if isinstance(o, (np.complexfloating, complex)):
        return {"re": _jsonable(o.real), "im": _jsonable(o.imag)}
    if isinstance(o, pathlib.Path):
        return str(o)
    return o


def _git_rev() -> str | None:
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True, text=True, timeout=10).stdout.strip()
        return rev + ("-dirty" if dirty else "") if rev else None
    except Exception:  # noqa: BLE001
        return None


def meta(args: argparse.Namespace, elapsed_s: float | None = None) -> dict:
    """Provenance recorded in every JSON: command, quick flag, runtime, versions, machine."""
    d = {
        "command": " ".join([".venv/bin/python", os.path.relpath(sys.argv[0], ROOT)] + sys.argv[1:]),
        "quick": bool(getattr(args, "quick", False)),
        "date": _dt.datetime.now().isoformat(timespec="seconds"),
        "git": _git_rev(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": f"{platform.machine()} {os.cpu_count()} logical CPUs ({platform.processor() or platform.platform()})",
    }
    try:
        import motes  # noqa: PLC0415

        d["motes"] = getattr(motes, "__version__", "?")
        d["AUTO_SIZE_PARAMETER"] = float(motes.AUTO_SIZE_PARAMETER)
        d["HYBRID_RADIUS_UM"] = float(motes.HYBRID_RADIUS_UM)
    except ImportError:
        pass
    try:
        d["loadavg_1_5_15"] = [round(x, 2) for x in os.getloadavg()]  # timings are noisy on a busy machine
    except OSError:
        pass
    if elapsed_s is not None:
        d["runtime_s"] = round(elapsed_s, 3)
    return d


def write_json(path: pathlib.Path, data: dict) -> None:
    path.write_text(json.dumps(_jsonable(data), indent=1))
    print(f"wrote {path}")


def finish(args: argparse.Namespace, sw: Stopwatch, path: pathlib.Path, **fields) -> None:
    """The end of a script: the JSON at ``path``, the provenance (:func:`meta`, with the run time on
    ``sw``) first and then ``fields``, and the run time printed."""
    elapsed = sw()
    write_json(path, dict(meta=meta(args, elapsed), **fields))
    print(f"runtime {elapsed:.1f} s")


def label(ax, xlabel: str, ylabel: str, title: str | None = None, *, legend: int | None = None, grid_which: str = "both") -> None:
    """Axis labels, optional title and legend (font size), and the light grid every figure uses."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title is not None:
        ax.set_title(title)
    if legend is not None:
        ax.legend(fontsize=legend)
    ax.grid(True, which=grid_which, alpha=0.3)


def save_fig(fig, path: pathlib.Path, rect=None) -> None:
    """Tight layout (inside ``rect``, e.g. to leave room for a suptitle), write, close."""
    import matplotlib.pyplot as _plt  # noqa: PLC0415

    fig.tight_layout(rect=rect)
    fig.savefig(path)
    _plt.close(fig)
    print(f"wrote {path}")


def eta_label(eta) -> str:
    e = complex(eta)
    return f"{e.real:g}" if e.imag == 0 else f"{e.real:g}+{e.imag:g}i"
