"""Issue 24.3: a procedural cloud (storage = procedural: no particle stored, bricks generated on demand)
against a stored cloud of the same distribution (compact storage), everything else at the shipped scene's
defaults (dust_box: spot and area light, Eq. 23 footprint), sparse visible grains (count 20000) and a dense
cloud (400000). Each storage renders one image per cloud seed (seeds 0..N-1: a new cloud every time, so
the SE holds the cloud-to-cloud variance too); image means compared in SE, and the render time of a
second pass (warm cache) side by side.

    .venv/bin/python scripts/bench/bench_procedural.py [--variant llvm_ad_rgb] [--seeds 8] [--res 64] [--spp 32]
    .venv/bin/python scripts/bench/bench_procedural.py --median 1500 --counts 400000 --seeds 6   (grains as wide as their spacing)
"""
import argparse, time
import numpy as np
import motes

ap = argparse.ArgumentParser()
ap.add_argument("--out", default="out", help="unused (run_benchmarks.sh passes it); results are printed")
ap.add_argument("--variant", default="llvm_ad_rgb")
ap.add_argument("--seeds", type=int, default=8)
ap.add_argument("--res", type=int, default=64)
ap.add_argument("--spp", type=int, default=32)
ap.add_argument("--counts", default="20000,400000")
ap.add_argument("--median", type=float, default=None, help="radius_median in um (default: the scene's 60)")
a = ap.parse_args()
motes.set_variant(a.variant)
import mitsuba as mi  # noqa: E402

src = open("scenes_xml/dust_box.xml").read()


def scene(storage, seed, count):
    t = src.replace('<medium type="discrete" name="interior">',
                    f'<medium type="discrete" name="interior">\n<string name="storage" value="{storage}"/>'
                    f'<integer name="seed" value="{seed}"/>')
    t = t.replace('<default name="count" value="20000"/>', f'<default name="count" value="{count}"/>')
    if a.median:
        t = t.replace('<float name="radius_median" value="60"/>', f'<float name="radius_median" value="{a.median}"/>')
    return mi.load_string(t, res=a.res, spp=a.spp)


print(f"{a.variant}, {a.res} px, {a.spp} spp, {a.seeds} clouds per storage")
for count in [int(float(c)) for c in a.counts.split(",")]:
    means, times = {}, {}
    for st in ("compact", "procedural"):
        m, t = [], []
        for s in range(a.seeds):
            sc = scene(st, s, count)
            m.append(float(np.asarray(mi.render(sc, spp=a.spp, seed=s), dtype=np.float64).mean()))
            t0 = time.perf_counter()
            np.asarray(mi.render(sc, spp=a.spp, seed=100 + s))
            t.append(time.perf_counter() - t0)
        means[st], times[st] = np.array(m), np.array(t)
    se = np.hypot(means["compact"].std(ddof=1), means["procedural"].std(ddof=1)) / np.sqrt(a.seeds)
    d = means["procedural"].mean() - means["compact"].mean()
    ratio = np.median(times["procedural"]) / np.median(times["compact"])
    print(f"count {count}: procedural - compact {d / means['compact'].mean():+.2%} ({d / se:+.1f} SE); "
          f"render (warm) {np.median(times['compact']):.2f} s compact, {np.median(times['procedural']):.2f} s "
          f"procedural ({ratio:.2f}x)")
