"""A procedural cloud's grains regenerated in Dr.Jit (``motes/drjit_procedural.py``, issue 46) against the Rust
core's (``DiscreteMedium.procedural_tile_grains``): per tile the same candidate count and per grain the same
tile, key, class, centre and scene position, bit for bit, for uniform, gradient and noise densities, both
Poisson samplers (lambda < 12 and above), several seeds, and grains moved by the turbulent drift; R and tau
are the class's as the core's bricks store them."""

from __future__ import annotations

import numpy as np
import pytest

import mitsuba as mi

import motes
from motes.discrete import DiscreteMedium

RGB = motes.RGB_WAVELENGTHS_UM
SPECIES = motes.Species(motes.LogNormal(80.0, 1.3), 1.5)
BOX = np.diag([0.06, 0.06, 0.06, 1.0])


@pytest.fixture(scope="module", autouse=True)
def _variant():
    if "llvm_ad_rgb" not in mi.variants():
        pytest.skip("needs the llvm_ad_rgb variant")
    previous = mi.variant()
    mi.set_variant("llvm_ad_rgb")
    yield
    if previous:
        mi.set_variant(previous)


def _medium(count=3e4, wavelength=RGB, query_radius=2e-4, **kw):
    kw.setdefault("to_world", BOX)
    return DiscreteMedium.procedural(count, [SPECIES], [1.0], wavelength, query_radius=query_radius,
                                     continuous_count=np.inf, cache_bytes=2**24, **kw)


def _check(medium, tiles):
    """The Dr.Jit grains of ``tiles`` equal the core's to the last bit; returns how many there are."""
    from motes.drjit_procedural import DrJitProcedural

    gen = DrJitProcedural(medium)
    got = gen.grains(np.asarray(tiles, dtype=np.uint32))
    want = medium._core.procedural_tile_grains([int(t) for t in tiles])
    assert np.array_equal(got["candidates"].numpy(), want["candidates"])
    for k in ("tile", "key", "code"):
        assert np.array_equal(np.asarray(got[k].numpy()), want[k]), k
    for k in ("centre", "position"):
        a = np.stack([x.numpy() for x in got[k]], axis=1).ravel()
        assert a.shape == want[k].shape and np.array_equal(a, want[k]), k
    e = gen.export
    code = want["code"].astype(np.int64)
    assert np.array_equal(got["reach"].numpy(), e["reach"][code])
    assert np.array_equal(got["tau"].numpy(), e["tau"][code])
    assert np.array_equal(got["bin"].numpy(), e["bin"][code])
    return len(want["key"]), gen, got


@pytest.mark.parametrize("seed", [0, 7, 2**64 - 3])
def test_uniform_grains_are_the_cores(seed):
    """~60 candidates a tile (the rejection sampler): a third of the tiles, in a scrambled order."""
    m = _medium(cloud_seed=seed)
    from motes.drjit_procedural import DrJitProcedural

    n_tiles = DrJitProcedural(m).tiles
    tiles = np.random.default_rng(seed % 1000).permutation(n_tiles)[: n_tiles // 3]
    n, gen, got = _check(m, tiles)
    assert gen.lam >= 12 and n > 50 * len(tiles)


def test_knuth_sampler_below_a_mean_of_12():
    """A cloud of 6 expected grains is one tile of lambda ~ 6: Knuth's product of uniforms, over 8 seeds."""
    counts = []
    for seed in range(8):
        m = _medium(6.0, wavelength=[0.55], size_bins=4, cloud_seed=seed)
        n, gen, got = _check(m, [0])
        assert gen.tiles == 1 and gen.lam < 12
        counts.append(n)
    assert 2 < np.mean(counts) < 12


@pytest.mark.parametrize("density", [("gradient", [2.0, 0.1, 1.0]), ("noise", [0.4, 3.0, 0.9])])
def test_thinned_densities(density):
    """Gradient and fBm noise densities: thinning, and the kept grains' indices in their tiles' keys."""
    m = _medium(density=density, noise_seed=5, cloud_seed=3)
    from motes.drjit_procedural import DrJitProcedural

    tiles = np.arange(0, DrJitProcedural(m).tiles, 3)
    n, gen, got = _check(m, tiles)
    assert gen.kind == density[0]
    cand = int(got["candidates"].numpy().sum())
    assert 0.1 * cand < n < 0.95 * cand  # some candidates were thinned


@pytest.mark.parametrize("density", [("gradient", [0.0, 3.0, 0.5]), ("noise", [0.3, 4.0, 1.2])])
def test_densities_are_the_cores(density):
    """The thinning's density at random points (some outside the box) to the last bit: the grains' test sees
    only its decisions, which a rounding-level error would flip about once in 1e16 candidates."""
    from motes.drjit_procedural import DrJitProcedural

    kind, params = density
    gen = DrJitProcedural(_medium(3e3, wavelength=[0.55], size_bins=4, density=density, noise_seed=8))
    p = np.random.default_rng(2).uniform(-1.3, 1.3, (20_000, 3))
    got = gen.density([mi.Float64(p[:, a]) for a in range(3)]).numpy()
    want = motes._motes.density_at(kind, params, 8, p.ravel(), [-1.0] * 3, [1.0] * 3)
    assert np.array_equal(got, want)


def test_drifting_grains():
    """The turbulent drift moves each grain's scene position (the curl of three value noises)."""
    m = _medium(turbulence=0.004, turbulence_scale=0.03, time_s=1.3, cloud_seed=4, wavelength=[0.55])
    still = _medium(cloud_seed=4, wavelength=[0.55])
    from motes.drjit_procedural import DrJitProcedural

    tiles = np.arange(0, DrJitProcedural(m).tiles, 5)
    n, gen, got = _check(m, tiles)
    assert gen.motion is not None
    moved = np.stack([x.numpy() for x in got["position"]], axis=1)
    rest = np.stack([x.numpy() for x in DrJitProcedural(still).grains(tiles)["position"]], axis=1)
    shift = np.linalg.norm(moved - rest, axis=1)
    assert shift.max() > 1e-4 and shift.max() < 0.1


def test_refusals():
    from motes.drjit_procedural import DrJitProcedural

    gen = DrJitProcedural(_medium(3e3))
    with pytest.raises(ValueError, match="tile"):
        gen.grains([gen.tiles])
    with pytest.raises(ValueError, match="tile"):
        _medium(3e3)._core.procedural_tile_grains([gen.tiles])
    stored = DiscreteMedium(np.zeros((1, 3)), np.array([50.0]), np.array([0]), [SPECIES], RGB)
    with pytest.raises(ValueError, match="procedural"):
        DrJitProcedural(stored)
    assert len(gen.grains(np.zeros(0, dtype=np.uint32))["key"]) == 0


def _rays(n, seed):
    """Rays through and beside the 12 cm cube: oblique ones, and ones along z (no motion along x and y),
    starting outside it and inside it."""
    rng = np.random.default_rng(seed)
    o = np.column_stack([rng.uniform(-0.07, 0.07, n), rng.uniform(-0.07, 0.07, n), rng.uniform(-0.2, 0.0, n)])
    d = np.column_stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.4, 0.4, n), np.ones(n)])
    d[: n // 4, :2] = 0.0
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d, rng.uniform(0.0, 0.1, n), rng.uniform(0.1, 0.4, n)


@pytest.mark.parametrize("kw", [dict(count=1e6), dict(count=3e4, query_radius=2e-3, turbulence=1e-4,
                                                      turbulence_scale=0.01, time_s=1.3),
                                dict(count=1e5, query_radius=1.2e-2)],
                         ids=["uniform", "drift", "wide"])
def test_optical_depth_is_the_cores(kw):
    """The walk that regenerates every tile a ray needs gives the core's optical depth (its bricks' grids)
    on each ray; here to the last bit (the taus are float32, their sums in float64 exact). A thinned density
    takes the same path (``_candidate``) as ``grains``, tested above."""
    from motes.drjit_procedural import DrJitProcedural

    m = _medium(wavelength=[0.55], size_bins=4, **kw)
    gen = DrJitProcedural(m)
    o, d, t0, t1 = _rays(16 if "turbulence" in kw else 48, 3)
    got = gen.optical_depth([mi.Float64(o[:, a]) for a in range(3)], [mi.Float64(d[:, a]) for a in range(3)],
                            mi.Float64(t0), mi.Float64(t1)).numpy()
    want = m.optical_depth(o, d, t0, t1)
    assert (want > 0).sum() > len(want) // 3
    assert max(gen.halo) == (2 if kw.get("query_radius", 0) > 1e-2 else 1)
    np.testing.assert_array_equal(got, want)


def _stream_uniform(seed, key):
    """``rng::stream_bits(seed, key)``'s top 53 bits as a uniform (numpy, wrapping uint64)."""
    with np.errstate(over="ignore"):
        z = np.uint64(seed) ^ (key * np.uint64(0xD1B54A32D192ED03))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53


def test_free_flights_stop_at_the_first_interacting_grain():
    """A free flight interacts at the grain of smallest t among those whose own uniform (hashed from the ray's
    seed and the grain's key) falls below 1 - exp(-tau_i): the same grain as a loop over every grain the core
    generates (numpy), on each ray, with the walk stopping early."""
    from motes.drjit_procedural import DrJitProcedural

    m = _medium(1e6, wavelength=[0.55], size_bins=4)
    gen = DrJitProcedural(m)
    o, d, t0, t1 = _rays(12, 4)
    # And rays across the whole cube (optical depth ~3: several grains interact, the walk keeps the first).
    rng = np.random.default_rng(6)
    o = np.vstack([o, np.column_stack([rng.uniform(-0.05, 0.05, (12, 2)), np.full(12, -0.07)])])
    d = np.vstack([d, np.column_stack([rng.uniform(-0.1, 0.1, (12, 2)), np.ones(12)])])
    d /= np.linalg.norm(d, axis=1)[:, None]
    t0, t1 = np.concatenate([t0, np.zeros(12)]), np.concatenate([t1, np.full(12, 0.14)])
    seeds = np.random.default_rng(5).integers(0, 2**63, size=len(o), dtype=np.uint64) * np.uint64(2) + np.uint64(1)
    t, key, code, valid = gen.sample_free_flight([mi.Float64(o[:, a]) for a in range(3)],
                                                 [mi.Float64(d[:, a]) for a in range(3)], mi.Float64(t0),
                                                 mi.Float64(t1), mi.UInt64(seeds))
    t, key, code, valid = t.numpy(), key.numpy(), code.numpy(), valid.numpy()
    g = m._core.procedural_tile_grains(list(range(gen.tiles)))
    px, py, pz = (g["position"][a::3].astype(np.float32).astype(np.float64) for a in range(3))
    keys, codes = g["key"], g["code"]
    reach = gen.export["reach"][codes].astype(np.float64)
    tau = gen.export["tau"][codes].astype(np.float64)
    found = 0
    for k in range(len(o)):
        vx, vy, vz = px - o[k, 0], py - o[k, 1], pz - o[k, 2]
        tt = vx * d[k, 0] + vy * d[k, 1] + vz * d[k, 2]
        qx, qy, qz = vx - tt * d[k, 0], vy - tt * d[k, 1], vz - tt * d[k, 2]
        q2 = qx * qx + qy * qy + qz * qz
        hit = (q2 < reach * reach) & (tt >= t0[k]) & (tt < t1[k])
        inter = np.zeros_like(hit)
        inter[hit] = _stream_uniform(seeds[k], keys[hit]) < -np.expm1(-tau[hit])
        assert valid[k] == inter.any(), k
        if inter.any():
            j = np.flatnonzero(inter)[np.argmin(tt[inter])]
            assert (t[k], key[k], code[k]) == (tt[j], keys[j], codes[j]), k
            found += 1
        else:
            assert t[k] == np.inf
    assert 3 <= found <= len(o) - 3, found
