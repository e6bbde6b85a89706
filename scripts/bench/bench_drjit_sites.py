"""Issue 46, the drjit kernel's pieces on one shipped scene's own grains and rays (default ``cornell``, exact:
``continuous_count = inf``), each against the core, to find where an image difference comes from:

* optical depths: ``DrJitGrid.optical_depth`` against ``DiscreteMedium.optical_depth`` on 20 000 rays from the
  camera's side of the cloud, from its box's faces (inwards) and from inside;
* free flights: ``intersect_aabb`` on ``--rays`` rays (from the camera's side and from inside, each to the
  box's face): the share that escapes against the mean of exp(-tau) of the core's optical depth (its standard
  error beside it), and the mean of the event's P = (1 - exp(-tau_event)) / (1 - exp(-tau_all)) (about 0.5);
* the phase function at those sites: the sampled 1 - mu in 30 bins (log-spaced) against the integral of the
  evaluated pdf over each bin (stratified, 4000 directions a bin), z per bin; the largest relative difference
  of ``sample``'s pdf and ``eval_pdf``'s at the sampled direction; the mean weight per channel.

    .venv/bin/python scripts/bench/bench_drjit_sites.py [--scene cornell] [--rays 1000000] [--res 32]

The camera's side: rays from just inside the box's face towards the camera (+z), aimed at the far face.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="cornell")
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--res", type=int, default=32)
    args = ap.parse_args()
    import motes  # noqa: PLC0415

    motes.set_variant("llvm_ad_rgb")
    import drjit as dr  # noqa: PLC0415
    import mitsuba as mi  # noqa: PLC0415

    sys.path.insert(0, str(ROOT / "scripts" / "bench"))
    import bench_drjit_kernel  # noqa: PLC0415

    sc = bench_drjit_kernel.load(mi, args.scene, args.res, {"kernel": "drjit", "continuous_count": "inf"})
    med = next(s.interior_medium() for s in sc.shapes() if s.interior_medium() is not None)
    k = med._drjit.ready()
    core = k.data()
    box = next(s for s in sc.shapes() if s.interior_medium() is not None).bbox()
    lo, hi = np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)
    rng = np.random.default_rng(0)
    F = mi.Float

    def jit3(a, T):
        return T(*[F(a[:, i].astype(np.float32)) for i in range(3)])

    def rays(kind, m):
        """Origins and unit directions (float32 values) of ``m`` rays, and their distance to the box's face."""
        if kind == "camera":
            o = np.empty((m, 3))
            o[:, :2] = rng.uniform(-1e-3, 1e-3, (m, 2)) + (lo[:2] + hi[:2]) / 2
            o[:, 2] = hi[2] - 1e-3 * (hi[2] - lo[2])
            tgt = rng.uniform(lo, hi, (m, 3))
            tgt[:, 2] = lo[2]
            d = tgt - o
        elif kind == "face":
            o = rng.uniform(lo, hi, (m, 3))
            ax, side = rng.integers(0, 3, m), rng.integers(0, 2, m)
            o[np.arange(m), ax] = np.where(side == 1, hi[ax], lo[ax])
            d = rng.normal(size=(m, 3))
            out = (d[np.arange(m), ax] > 0) == (side == 1)
            d[out, ax[out]] *= -1
        else:
            o = rng.uniform(lo, hi, (m, 3))
            d = rng.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        o, d = o.astype(np.float32).astype(np.float64), d.astype(np.float32).astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d > 0, (hi - o) / d, (lo - o) / d)
        return o, d, np.nan_to_num(t, nan=np.inf).min(axis=1).astype(np.float32).astype(np.float64)

    # The phase check compares every site with the first one's pdf: one optics bin (a monodisperse cloud).
    if int(np.max(np.asarray(core.core.flat_arrays()["bin"]))) != 0:
        raise SystemExit(f"{args.scene}: several optics bins; the phase check needs a monodisperse cloud")
    print(f"{args.scene} exact, {k.grid.count} grains, extent {k.extent:.3g}")
    for kind in ("camera", "face", "inside"):
        o, d, tmax = rays(kind, 20000)
        want = core.optical_depth(o, d, 0.0, tmax)
        got = np.asarray(k.grid.optical_depth(jit3(o, mi.Point3f), jit3(d, mi.Vector3f), F(tmax)), dtype=np.float64)
        print(f"optical depth from {kind:6s}: mean {want.mean():.5f}, relative difference of the sums "
              f"{(got.sum() - want.sum()) / want.sum():+.1e}, |difference| > 1e-3 on {np.mean(np.abs(got - want) > 1e-3):.5f}")
    for kind in ("camera", "inside"):
        esc, expect, P, sites = [], [], [], None
        for _ in range(max(args.rays // 200_000, 1)):
            o, d, tmax = rays(kind, min(args.rays, 200_000))
            ray = mi.Ray3f(jit3(o, mi.Point3f), jit3(d, mi.Vector3f))
            ray.maxt = F(tmax.astype(np.float32))
            valid, mint, _ = k.intersect_aabb(ray)
            v, t = np.asarray(valid), np.asarray(mint, dtype=np.float64)
            tau_all = core.optical_depth(o, d, 0.0, tmax)
            esc.append(~v)
            expect.append(np.exp(-tau_all))
            P.append((1 - np.exp(-core.optical_depth(o[v], d[v], 0.0, t[v]))) / (1 - np.exp(-tau_all[v])))
            if sites is None:
                sites = (ray, valid, mint)
        esc, expect, P = np.concatenate(esc), np.concatenate(expect), np.concatenate(P)
        se = np.sqrt(np.mean(expect * (1 - expect)) / esc.size)
        print(f"free flights from {kind:6s}: escape {esc.mean():.5f}, expected {expect.mean():.5f} +- {se:.5f}; "
              f"event P mean {P.mean():.4f}")
        phase(mi, dr, k, rng, *sites)


def phase(mi, dr, k, rng, ray, valid, mint) -> None:
    """The phase function at the sites of one batch of flights (module docs)."""
    F = mi.Float
    m = dr.width(mint)
    mei = dr.zeros(mi.MediumInteraction3f, m)
    mei.t, mei.p, mei.wi = mint, ray(mint), -ray.d
    mei.sh_frame = mi.Frame3f(mei.wi)
    ctx = mi.PhaseFunctionContext()
    u = [F(rng.random(m).astype(np.float32)) for _ in range(3)]
    wo, w, pdf = k.sample(ctx, mei, u[0], mi.Point2f(u[1], u[2]), valid)
    val, pdf_eval = k.eval_pdf(ctx, mei, wo, valid)
    v = np.asarray(valid)
    ch = len(w) if hasattr(w, "__len__") else 1
    w = np.stack([np.asarray(w[c]) for c in range(ch)], 1)[v]
    pdf, pdf_eval = np.asarray(pdf)[v], np.asarray(pdf_eval)[v]
    wi = -np.stack([np.asarray(mei.wi[a]) for a in range(3)], 1)[v]
    x = 1 - np.sum(wi * np.stack([np.asarray(wo[a]) for a in range(3)], 1)[v], axis=1)
    edges = np.concatenate([[0.0], np.geomspace(1e-5, 2.0, 30)])
    got = np.histogram(x, edges)[0] / x.size
    # The evaluated pdf's integral over each bin at the first site (stratified in 1 - mu; every site of a
    # monodisperse cloud has the same table).
    per = 4000
    xx = np.concatenate([rng.uniform(a, b, per) for a, b in zip(edges[:-1], edges[1:])])
    st, ph = np.sqrt(xx * (2 - xx)), 2 * np.pi * rng.random(xx.size)
    local = np.stack([st * np.cos(ph), st * np.sin(ph), 1 - xx], 1)
    first = int(np.flatnonzero(v)[0])
    one = dr.zeros(mi.MediumInteraction3f, xx.size)
    one.t = F(float(np.asarray(mint)[first]))
    one.p = mi.Point3f(*[float(np.asarray(mei.p[a])[first]) for a in range(3)])
    one.wi = mi.Vector3f(*[float(-c) for c in wi[0]])
    one.sh_frame = mi.Frame3f(one.wi)
    frame = mi.Frame3f(mi.Vector3f(*[float(c) for c in wi[0]]))
    dirs = frame.to_world(mi.Vector3f(*[F(local[:, a].astype(np.float32)) for a in range(3)]))
    _, p_at = k.eval_pdf(ctx, one, dirs, True)
    want = np.asarray(p_at, dtype=np.float64).reshape(-1, per).mean(axis=1) * 2 * np.pi * np.diff(edges)
    z = (got - want) / np.sqrt(np.maximum(want, 1e-12) / x.size)
    print(f"  phase at {x.size} sites: sampled-vs-evaluated z per bin: max |z| {np.abs(z).max():.1f}, chi2/bins "
          f"{np.mean(z ** 2):.2f}; pdf sample/eval max rel diff {np.max(np.abs(pdf_eval / pdf - 1)):.1e}; mean "
          f"weight {np.array2string(w.mean(axis=0), precision=5)}")


if __name__ == "__main__":
    main()
