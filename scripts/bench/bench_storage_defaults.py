"""Issue 24.2, defaults: compact against full storage with everything else at the shipped scene's defaults
(dust_box: spot and area light, sparse visible grains), and a dense default cloud (count 400000, nothing else
set) in the same room: image means in SE and per-pixel RMS over every pair of distinct seeds against noise.

    .venv/bin/python scripts/bench/bench_storage_defaults.py   (64 px, 32 spp x 6 seeds per storage)
"""
import sys, numpy as np, motes
motes.set_variant("llvm_ad_rgb")
import mitsuba as mi
src = open("scenes_xml/dust_box.xml").read()
def scene(storage, count=None):
    t = src.replace('<medium type="discrete" name="interior">',
                    f'<medium type="discrete" name="interior">\n<string name="storage" value="{storage}"/>')
    if count:
        t = t.replace('<default name="count" value="20000"/>', f'<default name="count" value="{count}"/>')
    return mi.load_string(t, res=64, spp=32)
for count in (None, 400000):
    imgs = {}
    for st in ("full", "compact"):
        sc = scene(st, count)
        imgs[st] = np.stack([np.asarray(mi.render(sc, spp=32, seed=s), dtype=np.float64).mean(axis=2) for s in range(6)])
    m = {k: v.mean(axis=(1, 2)) for k, v in imgs.items()}
    se = np.hypot(m["full"].std(ddof=1), m["compact"].std(ddof=1)) / np.sqrt(6)
    d = m["compact"].mean() - m["full"].mean()
    pairs = [(i, j) for i in range(6) for j in range(6) if i != j]
    noise = np.sqrt(np.mean([np.mean((imgs["full"][i] - imgs["full"][j]) ** 2) for i, j in pairs]))
    rms = np.sqrt(np.mean([np.mean((imgs["compact"][i] - imgs["full"][j]) ** 2) for i, j in pairs]))
    print(f"count {count or 20000}: compact - full {d / m['full'].mean():+.2%} ({d / se:+.1f} SE), rms/noise {rms / noise:.2f}")
