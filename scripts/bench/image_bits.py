"""Bitwise A/B of two builds' images: render a few shipped scenes (small, fixed seed) into an .npz, then
compare two such files pixel for pixel. The check behind "images bitwise unchanged" in BENCHMARKS.md:

    PYTHONPATH=/tmp/basepkg .venv/bin/python scripts/bench/image_bits.py render llvm_ad_rgb /tmp/base.npz
    .venv/bin/python scripts/bench/image_bits.py render llvm_ad_rgb /tmp/new.npz
    .venv/bin/python scripts/bench/image_bits.py compare /tmp/base.npz /tmp/new.npz

(`pip install --no-deps --target /tmp/basepkg <checkout of the other commit>` installs the other build.)
`--only NAME,NAME` renders a subset; `--kernel drjit` renders every discrete medium with the Dr.Jit kernel
(exact: `continuous_count = inf`, and its default) instead. Renders run on one Dr.Jit thread, so that two
renders of one build agree to the bit (several threads accumulate the film in a varying order). `compare A1,A2
B` takes several references: in scalar_rgb, and with `--kernel drjit` in llvm_ad_rgb (its default, the field
alone), the house scene renders one of two images from load to load (their means agree within noise; not yet
understood), so its reference is both.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

#: (name, scene file, overrides): every shipped scene at its defaults, plus the densest Cornell box.
SCENES = (
    ("cornell_dense", "cornell", {"count": "1000000", "radius": "2000"}),
    ("cornell", "cornell", {}),
    ("staircase", "staircase", {}),
    ("dust_box", "dust_box", {}),
    ("bench", "bench", {}),
    ("footprint", "footprint", {}),
    ("house", "house", {}),
    ("lamp", "lamp", {}),
    ("limit", "limit", {}),
)


def render(variant: str, out: str, only: set[str] | None = None, kernel: str | None = None) -> None:
    import motes  # noqa: PLC0415

    motes.set_variant(variant)
    import drjit as dr  # noqa: PLC0415
    import mitsuba as mi  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    # One Dr.Jit thread: the film then accumulates in a fixed order, so two renders of one build agree
    # to the bit (with several threads a few per cent of pixels differ in their last bits).
    dr.set_thread_count(1)
    images = {}
    for name, scene, overrides in SCENES:
        if only and name not in only:
            continue
        xml = Path(motes.__file__).parent / "scenes" / f"{scene}.xml"
        if kernel is None:
            sc = mi.load_file(str(xml), res="48", spp="8", **overrides)
            images[name] = np.asarray(mi.render(sc, spp=8, seed=3))
            continue
        for label, extra in (("", ""), ("_exact", '<float name="continuous_count" value="inf"/>')):
            tags = f'<string name="kernel" value="{kernel}"/>' + extra
            text = re.sub(r'(<medium type="discrete"[^>]*>)', lambda m: m.group(1) + tags, xml.read_text())
            sc = mi.load_string(text, res="48", spp="8", **overrides)
            images[name + label] = np.asarray(mi.render(sc, spp=8, seed=3))
    np.savez(out, **images)
    print(f"{motes.__file__}: wrote {out}")


def compare(a_files: str, b_file: str) -> int:
    """Compare ``b_file`` with one or more references (comma-separated): an image counts as identical when
    it equals any of them (a scene whose render takes one of a few forms from run to run)."""
    import numpy as np  # noqa: PLC0415

    refs, b = [np.load(f) for f in a_files.split(",")], np.load(b_file)
    differ = 0
    for k in refs[0].files:
        y = b[k]
        xs = [r[k] for r in refs if k in r.files]
        same = any(np.array_equal(x, y) for x in xs)
        x = next((x for x in xs if np.array_equal(x, y)), xs[0])
        d = np.abs(x - y)
        rel = d / np.maximum(np.abs(x), 1e-12)
        differ += not same
        print(f"{k}: identical={same} max_rel={rel.max():.3g} pixels_differing={np.mean(d > 0):.4f} "
              f"means {x.mean():.6g} {y.mean():.6g}")
    return differ


def main() -> None:
    kernel = None
    if "--kernel" in sys.argv:
        i = sys.argv.index("--kernel")
        kernel = sys.argv[i + 1]
        del sys.argv[i:i + 2]
    if len(sys.argv) in (4, 6) and sys.argv[1] == "render":
        only = set(sys.argv[5].split(",")) if len(sys.argv) == 6 and sys.argv[4] == "--only" else None
        render(sys.argv[2], sys.argv[3], only, kernel)
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        sys.exit(1 if compare(sys.argv[2], sys.argv[3]) else 0)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
