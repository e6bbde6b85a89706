"""A procedural cloud's discrete grains regenerated in Dr.Jit-typed code (issue 46: "procedural clouds
regenerate a cell's grains from the counter-based hash instead of storing them"): for a wavefront of tile
indices, each tile's grains as the Rust core's bricks generate them (``rust/motes-core/src/space/cloud.rs``,
``rust/motes-core/src/render/procedural/``), in the current Mitsuba variant's JIT types (``llvm_ad_*``, and
``cuda_ad_*``, where a kernel cannot call the core): the medium plugin's ``kernel = drjit`` in a procedural cloud.

The process (the core's module docs): tile t's stream is xoshiro256++ seeded by SplitMix64 from
``splitmix64(seed ^ splitmix64(TILE_STREAM ^ t))``; it draws the tile's candidate count K_t ~ Poisson(lambda)
(rand_distr 0.4's sampler: Knuth's product of uniforms for lambda < 12, else Numerical Recipes' rejection from
a Cauchy), then per candidate seven numbers ((x >> 11) + 0.5) 2^-53: the position in the tile (3), the thinning
(kept where u_3 bound < d(x); every candidate of a uniform density is kept), the discrete class (the first
class whose running probability exceeds u_4) and two the procedural cloud does not use. A kept grain's key is
((t << 24) | its index among the tile's kept grains) + 1; its scene position is the cloud's transform of its
centre, moved by the turbulent drift (``rust/motes-core/src/space/motion.rs``: the curl of three value noises
by central differences) where the cloud has one; its inclusion radius R and disk optical depth tau are its
class's, as the bricks' grids store them (float32).

Exactness: every step but the Poisson draw for lambda >= 12 is integer arithmetic and IEEE float64 additions,
multiplications, divisions by non-literal operands (Dr.Jit turns a division by a literal into a
multiplication by its reciprocal: hence ``_opaque``) and floors, in the core's order: the same bits as the
core. The rejection sampler's tan, log and exp are Dr.Jit's, not the C library's (a few ulps apart; Dr.Jit's
tan returns x for tiny x): its candidate floor(sqrt(2 lambda) tan(pi u) + lambda) and its acceptance
u' <= check can differ only where that value lies within ~4e-12 of an integer or u' within a few ulps of the
check, about 1e-11 per tile, so a tile's count is the core's except with that probability (a differing
tile then has different grains: another realisation of the same process there). ``tests/test_drjit_procedural.py``
checks the counts and grains against the core (``DiscreteMedium.procedural_tile_grains``) bit for bit in
``llvm_ad_rgb``. Not yet run in ``cuda_ad_*``: there the same bits also need the backend not to contract
a * b + c into a fused multiply-add (the LLVM backend does not) and IEEE float64 division.

Densities: uniform, gradient and fBm noise (a grid density is refused); the drift is supported.

``DrJitProcedural(medium)``: ``medium`` a procedural ``motes.DiscreteMedium`` (or its ``_motes`` core, or the
dict ``procedural_export`` returns); ``grains(tiles)`` returns the grains of those tiles as JIT arrays;
``optical_depth(o, d, t0, t1)`` walks rays through the cloud regenerating every tile they need and storing
nothing (a 3D-DDA over the tiles, grown by the halo a ball reaches across; per step the tiles of the halo
block no earlier step generated, of those only the ones whose box grown by the largest reach the segment meets,
and in those only the candidates whose rest position lies within that reach of the segment get their class and
the exact test: the others cannot meet it, so skipping them changes no bit): the core's
``DiscreteMedium.optical_depth`` of a cloud with no continuous classes, bit for bit on the tests' rays. Once a
step is done, every grain whose projection t_i lies before the step's exit has been tested (its ball reaches the
ray at t_i, inside the step's cell), so
``sample_free_flight`` (``drjit_walk``'s model: each grain interacts with probability 1 - exp(-tau_i) on its
own uniform, hashed from the ray's seed and its key) stops there: what the medium plugin would call for
``storage = "procedural"``.
``site_walk`` skips tiles and candidates alike (beyond the site's reach). A class is found from its number
through a guide of the running probabilities (a bucket's few classes searched, not all of them).
Rough cost (llvm, two shared cores): 1e6 grains of 15 625 tiles in 0.6 s; 4096 flights through lamp's
procedural cloud (5e5 grains in 8000 tiles of 62.5 candidates) 0.85 s of CPU, 5.0 s before the skips
(each ray draws the candidates of ~100-300 tiles; 0.34 s of the 0.85 s is that drawing alone); a tested
grain's interaction by an integer threshold per class (``_interact``) and the origin tag only where a ball
holds the origin: ~10 % less.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .drjit_walk import (EXCLUDE_MARGIN, face, fold_key, grain_hash, near, one_minus_exp, origin_hash,
                         cloud_tag_thresholds, point_exponent, tags_agree)

GOLDEN_GAMMA = 0x9E3779B97F4A7C15
#: ``rng::STREAM_GAMMA``: spreads a grain's key over a free flight's stream.
STREAM_GAMMA = 0xD1B54A32D192ED03
_M1, _M2 = 0xBF58476D1CE4E5B9, 0x94D049BB133111EB
#: rand_distr's Poisson: Knuth's method below this mean, the rejection method above.
KNUTH_BELOW = 12.0
#: ``rust/motes-core/src/space/motion.rs``: the curl's step, the pattern's speed and direction.
CURL_STEP = 1e-3
PATTERN_SPEED = 1.0
PATTERN_DIR = (0.381_966, 0.618_034, 0.688_191)
_UNIT = 2.0**-53
#: A bound on the drift over the turbulence (``Motion::drift_bound``: 10 sqrt(3) and 1 % more, rounded up).
DRIFT_PER_TURBULENCE = 17.6


def _export_of(medium) -> dict:
    if isinstance(medium, dict):
        return medium
    core = getattr(medium, "_core", medium)
    out = core.procedural_export()
    if out is None:
        raise ValueError("the medium has no procedural grains (stored particles, or every class continuous)")
    return out


def _opaque(x: float):
    """A Float64 the JIT does not fold into a literal (a division by it stays a division)."""
    return dr.opaque(mi.Float64, float(x))


def splitmix64_finalise(z):
    z = (z ^ (z >> 30)) * _M1
    z = (z ^ (z >> 27)) * _M2
    return z ^ (z >> 31)


def splitmix64(z):
    """SplitMix64's output for state ``z`` (``rust/motes-core/src/rng.rs``)."""
    return splitmix64_finalise(z + GOLDEN_GAMMA)


def _rotl(x, k: int):
    return (x << k) | (x >> (64 - k))


def _next(s):
    """xoshiro256++: (the next 64 bits, the advanced state); ``s`` a list of four UInt64."""
    s0, s1, s2, s3 = s
    out = _rotl(s0 + s3, 23) + s0
    t = s1 << 17
    s2 = s2 ^ s0
    s3 = s3 ^ s1
    s1 = s1 ^ s2
    s0 = s0 ^ s3
    s2 = s2 ^ t
    s3 = _rotl(s3, 45)
    return out, [s0, s1, s2, s3]


def _standard(bits):
    """rand's ``Standard`` f64 in [0, 1): the top 53 bits times 2^-53."""
    return mi.Float64(bits >> 11) * _UNIT


def _open(bits):
    """A candidate's number in (0, 1): ((x >> 11) + 0.5) 2^-53 (``visit_candidates``)."""
    return (mi.Float64(bits >> 11) + 0.5) * _UNIT


def _log_gamma(x):
    """rand_distr 0.4's ``log_gamma`` (the same operations in the same order)."""
    coefficients = (76.18009172947146, -86.50532032941677, 24.01409824083091, -1.231739572450155,
                    0.1208650973866179e-2, -0.5395239384953e-5)
    tmp = x + 5.5
    log = (x + 0.5) * dr.log(tmp) - tmp
    a = dr.full(mi.Float64, 1.000000000190015, dr.width(x))
    denom = mi.Float64(x)
    for c in coefficients:
        denom = denom + 1.0
        a = a + _opaque(c) / denom
    return log + dr.log(2.5066282746310005 * a / x)


class ValueNoise:
    """``rust/motes-core/src/space/cloud.rs``'s ``ValueNoise`` from its terms (``procedural_export``)."""

    def __init__(self, terms: dict):
        self.contrast = float(terms["contrast"])
        scale = float(terms["scale"])
        # Per octave: 2^o / scale (the core's f64 division, on the host), offsets, hash seed, weight.
        self.octaves = [(float(1 << o) / scale, [float(x) for x in off], int(base), 0.5**o)
                        for o, (off, base) in enumerate(zip(terms["offsets"], terms["bases"]))]

    def value(self, p, octaves=None):
        """v(p) in [0, 1] (Float64 triple); ``octaves`` in place of this noise's (f, offsets, hash seed, weight)
        per octave: another noise's of the same scale and octaves, its offsets and seeds JIT arrays."""
        U, I = mi.UInt64, mi.Int64
        total, weights = None, 0.0
        for f, off, base, weight in self.octaves if octaves is None else octaves:
            q = [p[a] * f + off[a] for a in range(3)]
            i = [dr.floor(x) for x in q]
            w = [_quintic(q[a] - i[a]) for a in range(3)]
            cell = [dr.reinterpret_array(U, I(x)) for x in i]
            acc = None
            for corner in range(8):
                c = [(corner >> a) & 1 for a in range(3)]
                h = splitmix64(splitmix64(splitmix64(base ^ (cell[0] + c[0])) ^ (cell[1] + c[1])) ^ (cell[2] + c[2]))
                ws = [w[a] if c[a] else 1.0 - w[a] for a in range(3)]
                term = ws[0] * ws[1] * ws[2] * (mi.Float64(h >> 11) * _UNIT)
                acc = term if acc is None else acc + term
            total = weight * acc if total is None else total + weight * acc
            weights += weight
        return dr.clip(total / _opaque(weights), 0.0, 1.0)

    def density(self, p):
        c = self.contrast
        return dr.clip(1.0 + c * (2.0 * self.value(p) - 1.0), 0.0, 1.0 + c)


def _quintic(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


class DrJitProcedural:
    """A procedural cloud's generator (module docs) in the current JIT variant."""

    def __init__(self, medium):
        if not mi.variant() or not mi.variant().startswith(("llvm_", "cuda_")):
            raise RuntimeError(f"motes.drjit_procedural needs a JIT variant (llvm_* or cuda_*), not {mi.variant()!r}")
        e = _export_of(medium)
        self.export = e
        self.seed = int(e["seed"])
        self.tile_stream = int(e["tile_stream"])
        self.dims = [int(x) for x in e["dims"]]
        self.tiles = self.dims[0] * self.dims[1] * self.dims[2]
        self.lo = [float(x) for x in e["lo"]]
        self.halo = [int(x) for x in e["halo"]]
        self.size = [float(x) for x in e["size"]]
        self.box_lo = [float(x) for x in e["box_lo"]]
        self.box_hi = [float(x) for x in e["box_hi"]]
        self.lam = float(e["lambda"])
        self.poisson = [float(x) for x in e["poisson"]]
        self.bound = float(e["bound"])
        d = e["density"]
        self.kind = d["kind"]
        if self.kind == "grid":
            raise ValueError("motes.drjit_procedural does not regenerate a grid density's cloud")
        if self.kind == "gradient":
            self.gradient = (int(d["axis"]), float(d["start"]), float(d["end"]))
        self.noise = ValueNoise(d["noise"]) if self.kind == "noise" else None
        self.index_bits = int(e["tile_index_bits"])
        self.to_scene = [[float(x) for x in row] for row in e["to_scene"]]
        m4 = np.vstack([np.asarray(self.to_scene, dtype=np.float64), [0.0, 0.0, 0.0, 1.0]])
        self.to_cloud = np.linalg.inv(m4)[:3].tolist()  # only to find the tiles a ray crosses
        m = e["motion"]
        self.motion = None
        if m is not None:
            self.motion = ([ValueNoise(t) for t in m["potential"]], float(m["turbulence"]), float(m["scale"]),
                           float(m["time"]))
            shapes = {(float(t["scale"]), len(t["bases"])) for t in m["potential"]}
            assert len(shapes) == 1, "the potential's three noises share a scale and octaves"
            self._pot_off = mi.Float64(np.asarray([t["offsets"] for t in m["potential"]], dtype=np.float64).ravel())
            self._pot_base = mi.UInt64(np.asarray([t["bases"] for t in m["potential"]], dtype=np.uint64).ravel())
            # The curl's pairs (i, j): d Psi_i / d q_j, in the order [d(2,1), d(1,2), d(0,2), d(2,0), d(1,0), d(0,1)].
            self._curl_i = mi.UInt32([2, 1, 0, 2, 1, 0])
            self._curl_j = mi.UInt32([1, 2, 2, 0, 0, 1])
        codes = np.asarray(e["codes"], dtype=np.uint32)
        self.n_codes = int(codes.size)
        self._codes = mi.UInt32(codes)
        cdf = np.asarray(e["cdf"], dtype=np.float64)
        self._cdf = mi.Float64(cdf)
        # ``_class``'s guide: the running probabilities' first index above b / M per bucket b (M a power of two, so
        # that floor(u M) and b / M are exact): the class of u in bucket b lies in [guide[b], guide[b + 1]], a
        # binary search of that bucket's few classes instead of log2(classes) steps over all (lamp's 16 384
        # classes, M = 65 536: 0.16 steps on average, where a heavy tail's bucket holds up to 2^10).
        assert np.all(np.diff(cdf) >= 0), "running probabilities"
        self._guide_m = 1 << min(int(np.ceil(np.log2(4 * max(codes.size, 1)))), 20)
        guide = np.minimum(np.searchsorted(cdf, np.arange(self._guide_m + 1) / self._guide_m, side="right"),
                           max(codes.size - 1, 0))
        self._guide = mi.UInt32(guide.astype(np.uint32))
        self._reach = mi.Float(np.asarray(e["reach"], dtype=np.float32))
        self._tau = mi.Float(np.asarray(e["tau"], dtype=np.float32))
        self._bin = mi.UInt32(np.asarray(e["bin"], dtype=np.uint32))
        # ``_test``'s interaction per class: u = (bits >> 11) 2^-53 < p = 1 - exp(-tau) exactly where the integer
        # bits >> 11 < ceil(p 2^53) (both sides scaled by a power of two), p as the walk computes it (the same
        # operations on the same float32 tau): a gather in place of an exp and a conversion per tested grain.
        p_i = np.asarray(one_minus_exp(mi.Float64(self._tau)), dtype=np.float64)
        self._interact = mi.UInt64(np.ceil(p_i * 2.0**53).astype(np.uint64))
        # Culling (``_walk``, ``_tile``): a grain meets a ray only within its reach of it, and its ball's centre
        # as the grids store it lies within the drift's bound and float32's rounding of its rest position.
        # ``near_reach``: that sum over the largest reach, in scene units, with 1e-6 of the cloud's extent (far
        # above float32's 6e-8 relative rounding) to spare; ``cell_reach``: the same per axis in tiles, through
        # the cloud's inverse transform (a scene step v moves cloud axis a by at most |row_a| |v|).
        drift = 0.0 if self.motion is None else DRIFT_PER_TURBULENCE * self.motion[1]
        reach_max = float(np.max(np.asarray(e["reach"], dtype=np.float64), initial=0.0))
        m4s = np.asarray(self.to_scene, dtype=np.float64)
        corners = np.array([[(self.box_lo, self.box_hi)[(k >> a) & 1][a] for a in range(3)] + [1.0]
                            for k in range(8)]) @ m4s.T
        scale = 1.0 + float(np.max(np.abs(corners))) + reach_max + drift
        self.near_reach = reach_max + drift + 1e-6 * scale
        rows = np.linalg.norm(np.asarray(self.to_cloud, dtype=np.float64)[:, :3], axis=1)
        self.cell_reach = [float(self.near_reach * rows[a] / self.size[a]) * (1 + 1e-9) for a in range(3)]
        # The origin tag's bits where balls are a few ulps wide (``drjit_walk.tag_thresholds``): the balls holding
        # a point where the density is at its bound (lambda candidates a tile, before thinning, each of a class by
        # the cdf): the densest region's, which errs towards more bits.
        share = np.diff(np.concatenate([[0.0], np.asarray(e["cdf"], dtype=np.float64)]))
        reach = np.asarray(e["reach"], dtype=np.float64)[codes]
        tile = float(np.prod(self.size)) * abs(float(np.linalg.det(m4s[:, :3])))
        self.holders = self.lam * float(np.sum(share * 4 / 3 * np.pi * reach**3)) / max(tile, 1e-300)
        # (None, the 6-bit tags alone, where no ball is a few ulps wide: ``scale`` bounds the coordinates in a ball.)
        self.tag_thresholds = cloud_tag_thresholds(self.holders, float(np.min(reach, initial=np.inf)), scale)

    # ---------------------------------------------------------------------------------------- the process

    def _seed(self, tile):
        """The tile's xoshiro256++ state: SplitMix64's first four outputs from the tile's seed."""
        x = splitmix64(self.seed ^ splitmix64(mi.UInt64(self.tile_stream) ^ tile))
        return [splitmix64_finalise(x + ((k + 1) * GOLDEN_GAMMA % 2**64)) for k in range(4)]

    def _poisson(self, s):
        """Each lane's candidate count (UInt32) and its stream after the draw (rand_distr 0.4's sampler)."""
        if not self.lam > 0:
            return dr.zeros(mi.UInt32, dr.width(s[0])), s
        if self.lam < KNUTH_BELOW:
            return self._knuth(s)
        return self._rejection(s)

    @dr.syntax
    def _knuth(self, s):
        n = dr.width(s[0])
        s0, s1, s2, s3 = s
        exp_l = self.poisson[0]
        result = dr.zeros(mi.Float64, n)
        p = dr.full(mi.Float64, 1.0, n)
        while p > exp_l:
            bits, (s0, s1, s2, s3) = _next([s0, s1, s2, s3])
            p = p * _standard(bits)
            result += 1.0
        return mi.UInt32(result - 1.0), [s0, s1, s2, s3]

    @dr.syntax
    def _rejection(self, s):
        n = dr.width(s[0])
        s0, s1, s2, s3 = s
        _, log_l, sqrt_2l, magic = self.poisson
        lam = self.lam
        result = dr.zeros(mi.Float64, n)
        done = dr.zeros(mi.Bool, n)
        while ~done:
            # A Cauchy deviate; below zero it is drawn again (the next iteration).
            bits, (s0, s1, s2, s3) = _next([s0, s1, s2, s3])
            comp = dr.tan(dr.pi * _standard(bits))
            result = sqrt_2l * comp + lam
            if result >= 0.0:
                result = dr.floor(result)
                check = 0.9 * (1.0 + comp * comp) * dr.exp(result * log_l - _log_gamma(1.0 + result) - magic)
                bits, (s0, s1, s2, s3) = _next([s0, s1, s2, s3])
                done = _standard(bits) <= check
        return mi.UInt32(result), [s0, s1, s2, s3]

    def density(self, p):
        """The relative density at cloud coordinates ``p`` (Float64 triple), as the core thins by it."""
        if self.kind == "uniform":
            return dr.full(mi.Float64, 1.0, dr.width(p[0]))
        if self.kind == "gradient":
            axis, start, end = self.gradient
            lo, hi = self.box_lo[axis], self.box_hi[axis]
            t = dr.clip((p[axis] - lo) / _opaque(hi - lo), 0.0, 1.0)
            return start + (end - start) * t
        return self.noise.density(p)

    @dr.syntax
    def _class(self, u):
        """The discrete class code whose interval of the running probabilities holds ``u``."""
        # dr.binary_search(0, n_codes - 1, cdf[i] <= u) (the first i with cdf[i] > u, else the last) within u's
        # bucket of the guide: u >= b / M, so every i below guide[b] has cdf[i] <= u; u < (b + 1) / M, so
        # cdf[guide[b + 1]] > u (or it is the last class).
        b = dr.minimum(mi.UInt32(u * self._guide_m), self._guide_m - 1)  # u rounds to 1.0 once in 2^53
        start = dr.gather(mi.UInt32, self._guide, b)
        end = dr.gather(mi.UInt32, self._guide, b + 1)
        while start < end:
            middle = (start + end) >> 1
            below = dr.gather(mi.Float64, self._cdf, middle) <= u
            start = dr.select(below, middle + 1, start)
            end = dr.select(below, end, middle)
        return dr.gather(mi.UInt32, self._codes, start)

    def _tile_lo(self, tile):
        """The low corner of tile ``tile`` (``Tiling::tile_lo``, Float64 triple)."""
        d0, d1 = self.dims[0], self.dims[1]
        idx = [tile % d0, (tile // d0) % d1, tile // (d0 * d1)]
        return [self.lo[a] + self.size[a] * mi.Float64(idx[a]) for a in range(3)]

    def _draw(self, s, tlo):
        """A candidate's seven numbers from the stream ``s``: (kept, centre, the class's number u_4 as its bits
        (``_open`` of them: a walk converts them only where it needs the class), the stream after)."""
        u = []
        for _ in range(7):
            bits, s = _next(s)
            u.append(bits)
        centre = [tlo[a] + self.size[a] * _open(u[a]) for a in range(3)]
        return self._kept(_open(u[3]), centre), centre, u[4], s

    def _candidate(self, s, tlo):
        """A candidate's seven numbers from the stream ``s``: (kept, centre, class code, the stream after)."""
        keep, centre, u_class, s = self._draw(s, tlo)
        return keep, centre, self._class(_open(u_class)), s

    @dr.syntax
    def _candidates(self, tile, s, count, first, out):
        """Each tile lane's candidates, in its stream's order, written from ``first``: centre, class, kept,
        index among the tile's kept (``out``: lists of JIT arrays of the candidates' count)."""
        tlo = self._tile_lo(tile)
        s0, s1, s2, s3 = s
        i = dr.zeros(mi.UInt32, dr.width(tile))
        kept = dr.zeros(mi.UInt32, dr.width(tile))
        while i < count:
            keep, centre, code, (s0, s1, s2, s3) = self._candidate([s0, s1, s2, s3], tlo)
            slot = first + i
            for a in range(3):
                dr.scatter(out["centre"][a], centre[a], slot)
            dr.scatter(out["code"], code, slot)
            dr.scatter(out["keep"], keep, slot)
            dr.scatter(out["index"], kept, slot)
            dr.scatter(out["tile"], tile, slot)
            kept += dr.select(keep, 1, 0)
            i += 1

    def _kept(self, u, centre):
        """Thinning: whether a candidate at ``centre`` with number ``u`` is kept (every one of a uniform density)."""
        if self.kind == "uniform":
            return dr.full(mi.Bool, True, dr.width(u))
        return u * self.bound < self.density(centre)

    def _scene(self, centre):
        """A grain's scene position: the transform of its centre, moved by the drift where there is one."""
        p = self._rest(centre)
        return p if self.motion is None else self._moved(p)

    def _moved(self, x0):
        """``Motion::position``: the rest position ``x0`` (scene units) moved by the drift to its time: x0 plus
        turbulence (W(q, t) - W(q, 0)), W the curl of the potential by central differences."""
        _, turbulence, scale, time = self.motion
        if time == 0.0:
            return list(x0)
        scale_ = _opaque(scale)
        q1 = [x0[a] / scale_ + time * PATTERN_SPEED * PATTERN_DIR[a] for a in range(3)]
        q0 = [x0[a] / scale_ + 0.0 * PATTERN_SPEED * PATTERN_DIR[a] for a in range(3)]
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            d = self._derivatives(q1, q0)
        w1 = [d[0] - d[1], d[2] - d[3], d[4] - d[5]]
        w0 = [d[6] - d[7], d[8] - d[9], d[10] - d[11]]
        return [x0[a] + turbulence * (w1[a] - w0[a]) for a in range(3)]

    @dr.syntax
    def _derivatives(self, q1, q0):
        """The twelve derivatives d Psi_i / d q_j of the curl (``Motion::curl``) at q1 (then q0), in the curl's
        order: one symbolic loop over them (a kernel of two noise evaluations, not 24)."""
        potential = self.motion[0]
        shape = potential[0].octaves
        n = dr.width(q1[0])
        h2 = _opaque(2.0 * CURL_STEP)
        d = [dr.zeros(mi.Float64, n) for _ in range(12)]
        k = dr.zeros(mi.UInt32, n)
        while k < 12:
            pair = k % 6
            i = dr.gather(mi.UInt32, self._curl_i, pair)
            j = dr.gather(mi.UInt32, self._curl_j, pair)
            q = [dr.select(k < 6, q1[a], q0[a]) for a in range(3)]
            lo = [dr.select(j == a, q[a] - CURL_STEP, q[a]) for a in range(3)]
            hi = [dr.select(j == a, q[a] + CURL_STEP, q[a]) for a in range(3)]
            octaves = [(shape[o][0], [dr.gather(mi.Float64, self._pot_off, (i * len(shape) + o) * 3 + a)
                                      for a in range(3)],
                        dr.gather(mi.UInt64, self._pot_base, i * len(shape) + o), shape[o][3])
                       for o in range(len(shape))]
            dv = (potential[0].value(hi, octaves) - potential[0].value(lo, octaves)) / h2
            d = [dr.select(k == m, dv, d[m]) for m in range(12)]
            k += 1
        return d

    # ---------------------------------------------------------------------------------------- queries

    def grains(self, tiles) -> dict:
        """The grains of ``tiles`` (linear tile indices, any integer array), in the order asked, each tile's
        in its stream's order: a dict of JIT arrays, ``candidates`` per tile asked (before thinning) and per
        grain ``tile`` (UInt32), ``key`` (UInt64), ``code`` and ``bin`` (UInt32), ``centre`` (the cloud's
        coordinates, three Float64), ``position`` (scene units, three Float64), ``reach`` and ``tau``
        (Float, as the bricks' grids store them)."""
        tile = mi.UInt32(tiles)
        if dr.width(tile) == 0:
            z, f = dr.zeros(mi.UInt32, 0), dr.zeros(mi.Float64, 0)
            return {"candidates": z, "tile": z, "key": dr.zeros(mi.UInt64, 0), "code": z, "bin": z,
                    "centre": [f, f, f], "position": [f, f, f], "reach": dr.zeros(mi.Float, 0),
                    "tau": dr.zeros(mi.Float, 0)}
        if int(dr.max(tile)[0]) >= self.tiles:
            raise ValueError(f"tile indices must be below the cloud's {self.tiles} tiles")
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            s = self._seed(mi.UInt64(tile))
            count, s = self._poisson(s)
            dr.eval(count, s)
            first = dr.prefix_sum(count)
            total = int(dr.sum(count)[0])
            out = {"centre": [dr.zeros(mi.Float64, total) for _ in range(3)], "code": dr.zeros(mi.UInt32, total),
                   "keep": dr.zeros(mi.Bool, total), "index": dr.zeros(mi.UInt32, total),
                   "tile": dr.zeros(mi.UInt32, total)}
            if total:
                self._candidates(tile, s, count, first, out)
                dr.eval(out)
        kept = dr.compress(out["keep"]) if total else dr.zeros(mi.UInt32, 0)
        g = {k: dr.gather(type(out[k]), out[k], kept) for k in ("code", "index", "tile")}
        centre = [dr.gather(mi.Float64, out["centre"][a], kept) for a in range(3)]
        limit = (1 << self.index_bits) - 1
        key = ((mi.UInt64(g["tile"]) << self.index_bits) | mi.UInt64(dr.minimum(g["index"], limit))) + 1
        position = self._scene(centre)
        return {"candidates": count, "tile": g["tile"], "key": key, "code": g["code"],
                "bin": dr.gather(mi.UInt32, self._bin, g["code"]), "centre": centre, "position": position,
                "reach": dr.gather(mi.Float, self._reach, g["code"]), "tau": dr.gather(mi.Float, self._tau, g["code"])}

    # ---------------------------------------------------------------------------------------- the walk

    def optical_depth(self, origin, direction, t0, t1):
        """Grey optical depth (Float64) of the segments [t0, t1) of the rays ``origin + t direction`` (scene
        units, |direction| = 1): the sum of tau_i over the grains whose ball (centre and R_i as the bricks'
        grids store them, float32) the ray passes within and whose projection t_i lies in the segment, as
        the core's ``DiscreteMedium.optical_depth`` of a cloud with no continuous classes. Every grain is
        regenerated where the ray needs it and nothing is stored: a 3D-DDA over the tiles the segment crosses
        (the cloud's coordinates, the tiling grown by the halo), and per step the tiles within the halo that
        no earlier step generated (the whole block at the first step, then the slab each move adds)."""
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            return self._walk(*_rays(origin, direction, t0, t1), None)[0]

    def sample_free_flight(self, origin, direction, t0, t1, seed, exclude_origin=None, tagged=False,
                           want_ball=False):
        """Exact free flights on [t0, tmax): ``(t, key, code, valid)``: the t of the first grain that interacts
        (Float64, inf where none), its key (UInt64) and class code (UInt32), and whether there is one. Each grain
        interacts with probability 1 - exp(-tau_i), independently: its uniform is the top 53 bits of
        ``splitmix64_finalise(seed ^ key * STREAM_GAMMA)`` (``rng::stream_bits`` of the ray's 64-bit ``seed``,
        a UInt64 per ray, and the grain's key), so the walk need not meet grains in t order and stops after
        the first DDA step whose exit lies beyond an interaction (module docs): the distribution the core's
        free flight samples, not its sample. ``exclude_origin`` (a mask per ray, or None): those rays skip the
        grains whose ball holds their origin (grown by ``drjit_walk.EXCLUDE_MARGIN``), as
        ``DrJitGrid.sample_free_flight`` does (a ray leaving a site); ``tagged``: only those whose tag the origin
        carries (``drjit_walk.tags_agree``, the grain's hash ``grain_hash(fold_key(key))``). ``want_ball``: a fifth
        value, the grain's ball (centre [x, y, z] as the bricks store it and R, Float64; 0 where none): the medium
        plugin's tag search keeps a site inside it."""
        o, d, t0, t1 = _rays(origin, direction, t0, t1)
        seed = mi.UInt64(seed) + dr.zeros(mi.UInt64, dr.width(t0))
        exclude = dr.zeros(mi.Bool, dr.width(t0)) if exclude_origin is None else \
            mi.Bool(exclude_origin) | dr.zeros(mi.Bool, dr.width(t0))
        if tagged:  # the origin's hash and the exponent its ulp scales with (``tags_agree``)
            n = dr.width(t0)
            exclude = (exclude, origin_hash(origin[0], origin[1], origin[2]) + dr.zeros(mi.UInt32, n),
                       point_exponent(origin[0], origin[1], origin[2]) + dr.zeros(mi.Int32, n))
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            _, t, key, code, centre = self._walk(o, d, t0, t1, seed, exclude, want_ball)
        valid = key != 0
        if want_ball:
            reach = dr.select(valid, mi.Float64(dr.gather(mi.Float, self._reach, code, valid)), 0.0)
            return t, key, code, valid, (centre, reach)
        return t, key, code, valid

    @dr.syntax
    def _walk(self, o, d, t0, t1, seed, exclude=None, ball=False):
        """(optical depth, and where ``seed`` is given the first interaction's t, key, class code and, with
        ``ball``, centre: an empty list without, three loop variables fewer; with a ``seed`` the optical depth is
        not summed, 0)."""
        F, I = mi.Float64, mi.Int32
        n = dr.width(o[0])
        m, h = self.to_cloud, self.halo
        # The ray in tile units of the grown tiling (cell c is tile c - halo).
        oc = [m[r][0] * o[0] + m[r][1] * o[1] + m[r][2] * o[2] + m[r][3] for r in range(3)]
        dc = [m[r][0] * d[0] + m[r][1] * d[1] + m[r][2] * d[2] for r in range(3)]
        dims = [self.dims[a] + 2 * h[a] for a in range(3)]
        at = [(oc[a] - (self.lo[a] - self.size[a] * h[a])) / _opaque(self.size[a]) for a in range(3)]
        per_t = [dc[a] / _opaque(self.size[a]) for a in range(3)]
        inv_p = [1.0 / p for p in per_t]
        t_in, t_out = F(t0), F(t1)
        for a in range(3):
            flat = per_t[a] == 0
            u0, u1 = (0.0 - at[a]) * inv_p[a], (dims[a] - at[a]) * inv_p[a]
            inside = (at[a] >= 0) & (at[a] <= dims[a])
            t_in = dr.maximum(t_in, dr.select(flat, dr.select(inside, -dr.inf, dr.inf), dr.minimum(u0, u1)))
            t_out = dr.minimum(t_out, dr.select(flat, dr.select(inside, dr.inf, -dr.inf), dr.maximum(u0, u1)))
        active = t_in < t_out
        # The DDA over the grown tiling's cells (cx, cy, cz), each axis' next face at tnx, tny, tnz.
        step = [dr.select(per_t[a] > 0, 1, dr.select(per_t[a] < 0, -1, 0)) for a in range(3)]
        c = [dr.clip(I(dr.floor(at[a] + t_in * per_t[a])), 0, dims[a] - 1) for a in range(3)]
        tnx, tny, tnz = (_face(c[a], at[a], per_t[a], inv_p[a]) for a in range(3))
        cx, cy, cz = c
        tau = dr.zeros(F, n)
        best_t = dr.full(F, dr.inf, n)
        best_key = dr.zeros(mi.UInt64, n)
        best_code = dr.zeros(mi.UInt32, n)
        best_centre = [dr.zeros(F, n) for _ in range(3)] if ball else []
        first = dr.full(mi.Bool, True, n)
        moved = dr.full(I, -1, n)
        while active:
            t_exit = dr.minimum(dr.minimum(tnx, tny), dr.minimum(tnz, t_out))
            # The tiles this step adds (real tile indices), clamped to the tiling.
            lo_, hi_ = [], []
            cc = (cx, cy, cz)
            for a in range(3):
                ca = cc[a]
                slab = ~first & (moved == a)
                edge = ca - h[a] + step[a] * h[a]
                lo_.append(dr.maximum(dr.select(slab, edge, ca - 2 * h[a]), 0))
                hi_.append(dr.minimum(dr.select(slab, edge, ca), self.dims[a] - 1))
            nx = dr.maximum(hi_[0] - lo_[0] + 1, 1)
            ny = dr.maximum(hi_[1] - lo_[1] + 1, 1)
            some = (hi_[0] >= lo_[0]) & (hi_[1] >= lo_[1]) & (hi_[2] >= lo_[2])
            count = dr.select(some, nx * ny * (hi_[2] - lo_[2] + 1), 0)
            # Only the tiles whose box grown by ``cell_reach`` the segment meets can hold a grain it meets: each
            # lane skips the others (``_next_met``), so the lanes regenerate their r-th such tile side by side.
            slab = (lo_, nx, ny, at, per_t, inv_p, t0, t1)
            r = self._next_met(dr.zeros(I, n), count, lambda k: self._met(k, slab))
            while r < count:
                tile = mi.UInt32(self._slab_tile(r, lo_, nx, ny))
                tau, best_t, best_key, best_code, best_centre = self._tile(
                    tile, o, d, t0, t1, seed, tau, best_t, best_key, best_code, best_centre, exclude)
                r = self._next_met(r + 1, count, lambda k: self._met(k, slab))
            cx, cy, cz, tnx, tny, tnz, moved, go = _advance((cx, cy, cz), (tnx, tny, tnz), step, at, per_t, inv_p,
                                                            t_out)
            # Every grain with t_i before this step's exit is tested: a flight that interacted there stops.
            go &= best_t > t_exit
            active = go & (cx >= 0) & (cx < dims[0]) & (cy >= 0) & (cy < dims[1]) & (cz >= 0) & (cz < dims[2])
            first = dr.full(mi.Bool, False, n)
        return tau, best_t, best_key, best_code, best_centre

    def _slab_tile(self, r, lo_, nx, ny, cells=False):
        """The r-th tile of the block lo_ .. lo_ + (nx, ny, *) (x fastest): its linear index, or its three
        tile coordinates with ``cells``."""
        t = [lo_[0] + r % nx, lo_[1] + (r // nx) % ny, lo_[2] + r // (nx * ny)]
        return t if cells else (t[2] * self.dims[1] + t[1]) * self.dims[0] + t[0]

    def _met(self, r, slab):
        """Whether the segment meets the r-th tile's box grown by ``cell_reach`` (in the grown tiling's cells,
        where tile t is cell t + halo): where it does not, no grain of the tile is within its reach of the
        segment, so none can be met (``near_reach``)."""
        lo_, nx, ny, at, per_t, inv_p, ta, tb = slab
        cell = self._slab_tile(r, lo_, nx, ny, cells=True)
        for a in range(3):
            c = cell[a] + self.halo[a]
            ta, tb = near(at[a], per_t[a], inv_p[a], c, c, self.cell_reach[a], ta, tb, mi.Float64)
        return ta <= tb

    @dr.syntax
    def _next_met(self, r, count, met):
        """The first r' >= r below ``count`` whose tile ``met(r')`` (a mask) admits, else ``count``."""
        while (r < count) & ~met(r):
            r += 1
        return r

    def _rest_near(self, q, o, d, t0, t1):
        """Whether a candidate's rest position ``q`` (scene units, double precision) lies within ``near_reach``
        of the segment: where not, neither its drifted nor its float32 centre is within any class's reach, so
        ``_meets`` fails; the class, the drift and the exact test are skipped (a projection t moves by at most
        the centre's move). (A bound per guide bucket of the classes' reach, one gather more, was no faster.)"""
        slack = self.near_reach
        v = [q[a] - o[a] for a in range(3)]
        t = v[0] * d[0] + v[1] * d[1] + v[2] * d[2]
        w = [v[a] - t * d[a] for a in range(3)]
        return (w[0] * w[0] + w[1] * w[1] + w[2] * w[2] < slack * slack) & (t >= t0 - slack) & (t < t1 + slack)

    @dr.syntax
    def _tile(self, tile, o, d, t0, t1, seed, tau, best_t, best_key, best_code, best_centre, exclude=None):
        """The grains of tile ``tile`` (one per lane, regenerated) on the rays: their optical depth added to
        ``tau`` and, with a ``seed``, the first interaction so far (``best_*``, module docs; ``best_centre`` an
        empty list where the caller does not want the ball)."""
        s0, s1, s2, s3 = self._seed(mi.UInt64(tile))
        count, (s0, s1, s2, s3) = self._poisson([s0, s1, s2, s3])
        tlo = self._tile_lo(tile)
        i = dr.zeros(mi.UInt32, dr.width(tile))
        kept = dr.zeros(mi.UInt32, dr.width(tile))
        while i < count:
            keep, centre, u_class, (s0, s1, s2, s3) = self._draw([s0, s1, s2, s3], tlo)
            q = self._rest(centre)
            # Most candidates lie beyond every reach of the ray: only the others get their class and the test.
            if keep & self._rest_near(q, o, d, t0, t1):
                tau, best_t, best_key, best_code, best_centre = self._test(
                    tile, kept, q, self._class(_open(u_class)), o, d, t0, t1, seed, tau, best_t, best_key, best_code,
                    best_centre, exclude)
            kept += dr.select(keep, 1, 0)
            i += 1
        return tau, best_t, best_key, best_code, best_centre

    @dr.syntax
    def _test(self, tile, kept, q, code, o, d, t0, t1, seed, tau, best_t, best_key, best_code, best_centre, exclude):
        """One kept candidate (rest position ``q``, class ``code``, index ``kept`` among its tile's kept) on the
        rays: ``_tile``'s update of ``tau`` and ``best_*``."""
        F = mi.Float64
        # The drift only where the rest position is within its bound of meeting the segment.
        reach, p = self._placed(True, q, code, lambda x, r_d: self._meets(x, r_d, o, d, t0 - r_d, t1 + r_d)[0])
        # The grain as the grids store it (float32 centre and R), tested in double precision
        # (``ball_contribution``, rust/motes-core/src/space/grid/slots.rs).
        pf = [F(mi.Float(x)) for x in p]
        hit, t = self._meets(pf, reach, o, d, t0, t1)
        limit = (1 << self.index_bits) - 1
        key = ((mi.UInt64(tile) << self.index_bits) | mi.UInt64(dr.minimum(kept, limit))) + 1
        if isinstance(exclude, tuple):  # the origin tag (``sample_free_flight``)
            v = [pf[a] - o[a] for a in range(3)]
            grown = reach * (1 + EXCLUDE_MARGIN)
            skip = exclude[0] & (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] < grown * grown)
            # Few balls hold the origin: their tag alone is read (its width, its hash and their comparison).
            if skip:
                skip = tags_agree(exclude[1], grain_hash(fold_key(key)), mi.Float(reach), exclude[2],
                                  self.tag_thresholds)
            hit &= ~skip
        elif exclude is not None:
            v = [pf[a] - o[a] for a in range(3)]
            grown = reach * (1 + EXCLUDE_MARGIN)
            hit &= ~(exclude & (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] < grown * grown))
        if seed is None:  # a flight needs no optical depth (its interaction: ``_interact``), a walk no flight
            tau = tau + dr.select(hit, F(dr.gather(mi.Float, self._tau, code, hit)), 0.0)
        else:
            bits = splitmix64_finalise(seed ^ (key * STREAM_GAMMA)) >> 11
            interacts = hit & (t < best_t) & (bits < dr.gather(mi.UInt64, self._interact, code, hit))
            best_t = dr.select(interacts, t, best_t)
            best_key = dr.select(interacts, key, best_key)
            best_code = dr.select(interacts, code, best_code)
            best_centre = [dr.select(interacts, pf[a], best_centre[a]) for a in range(len(best_centre))]
        return tau, best_t, best_key, best_code, best_centre

    # ---------------------------------------------------------------------------------------- a site

    def extent(self) -> float:
        """The largest side of the cloud's box in scene units (its corners transformed), grown by the largest
        reach and the drift's bound: what the core's coincidence window scales with (``event_geometry``)."""
        lo, hi = self.box_lo, self.box_hi
        m = np.asarray(self.to_scene, dtype=np.float64)
        corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] + [1.0] for k in range(8)]) @ m.T
        drift = 0.0 if self.motion is None else DRIFT_PER_TURBULENCE * self.motion[1]
        reach = float(np.max(np.asarray(self.export["reach"], dtype=np.float64), initial=0.0))
        return float(np.max(corners.max(axis=0) - corners.min(axis=0))) + reach + drift

    def site_walk(self, p, d_in, tol, visit, state, active=True, tag=None):
        """Visit every grain that could be part of a site at ``p`` on a ray along ``d_in`` (the grains of the tiles
        within the halo of ``p``'s tile, regenerated): ``state = visit(tau, bin, member, state)`` per grain that
        may be a member (its rest position within the site's reach of ``p``; ``visit`` must leave ``state`` as it is
        where ``member`` is False, as the medium plugin's steps do: the others are skipped), with
        ``member`` whether its ball holds the ray (centre and R as the grids store them, R grown by the base
        tolerance, which holds the flight's rounding of t) and its centre projects on it within ``tol`` of ``p``
        (``DiscreteMedium::site_near``'s rule, in double precision); ``tau`` (Float)
        and ``bin`` its optical depth and optics bin. ``state``: a list of JIT values, returned updated. ``tag`` =
        (the point's ``origin_hash``, a second tolerance, its ``point_exponent``): a member must then also have its tag
        there (``tags_agree``), or project within the second tolerance (the medium plugin's site rule)."""
        F = mi.Float64
        pp = [F(p[a]) for a in range(3)]
        dd = [F(d_in[a]) for a in range(3)]
        n = max(dr.width(pp[0]), dr.width(dd[0]), dr.width(tol))
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            if tag is not None:
                tag = (mi.UInt32(tag[0]) + dr.zeros(mi.UInt32, n), F(tag[1]) + dr.zeros(F, n),
                       mi.Int32(tag[2]) + dr.zeros(mi.Int32, n))
            return self._site_walk([x + dr.zeros(F, n) for x in pp], [x + dr.zeros(F, n) for x in dd],
                                   F(tol) + dr.zeros(F, n), visit, state, mi.Bool(active) | dr.zeros(mi.Bool, n), tag)

    @dr.syntax
    def _site_walk(self, p, d, tol, visit, state, active, tag=None):
        I = mi.Int32
        m, h = self.to_cloud, self.halo
        pc = [m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3] for r in range(3)]
        c = [I(dr.floor((pc[a] - self.lo[a]) / _opaque(self.size[a]))) for a in range(3)]
        lo_ = [dr.maximum(c[a] - h[a], 0) for a in range(3)]
        hi_ = [dr.minimum(c[a] + h[a], self.dims[a] - 1) for a in range(3)]
        nx = dr.maximum(hi_[0] - lo_[0] + 1, 1)
        ny = dr.maximum(hi_[1] - lo_[1] + 1, 1)
        some = active & (hi_[0] >= lo_[0]) & (hi_[1] >= lo_[1]) & (hi_[2] >= lo_[2])
        count = dr.select(some, nx * ny * (hi_[2] - lo_[2] + 1), 0)
        # A member's float32 centre lies within tol along the ray and its reach and the rim's tolerance across
        # of p, so its rest position within ``site_reach`` of p (``near_reach``): only the tiles whose box lies
        # that near (per axis in tiles, through the inverse transform's rows, ``cell_reach``) are regenerated.
        site_reach = self.near_reach + tol + (tag[1] if tag is not None else tol)
        at = [(pc[a] - self.lo[a]) / _opaque(self.size[a]) for a in range(3)]
        margin = [site_reach * (self.cell_reach[a] / self.near_reach) for a in range(3)]

        def met(k):
            cell = self._slab_tile(k, lo_, nx, ny, cells=True)
            # The distance from p to the tile's box [cell, cell + 1] along each axis, in tiles.
            gap = [dr.maximum(dr.maximum(mi.Float64(cell[a]) - at[a], at[a] - mi.Float64(cell[a] + 1)), 0.0)
                   for a in range(3)]
            return (gap[0] <= margin[0]) & (gap[1] <= margin[1]) & (gap[2] <= margin[2])

        r = self._next_met(dr.zeros(I, dr.width(p[0])), count, met)
        while r < count:
            tile = mi.UInt32(self._slab_tile(r, lo_, nx, ny))
            state = self._site_tile(tile, p, d, tol, visit, state, site_reach, tag)
            r = self._next_met(r + 1, count, met)
        return state

    @dr.syntax
    def _site_tile(self, tile, p, d, tol, visit, state, site_reach, tag=None):
        """``_site_walk``'s visit of one tile's grains; a candidate whose rest position lies beyond ``site_reach``
        of p is no member (``_site_walk``), and ``visit`` leaves the state as it is at a non-member, so it is
        skipped before its class is drawn."""
        s0, s1, s2, s3 = self._seed(mi.UInt64(tile))
        count, (s0, s1, s2, s3) = self._poisson([s0, s1, s2, s3])
        tlo = self._tile_lo(tile)
        i = dr.zeros(mi.UInt32, dr.width(tile))
        kept = dr.zeros(mi.UInt32, dr.width(tile))
        while i < count:
            keep, centre, u_class, (s0, s1, s2, s3) = self._draw([s0, s1, s2, s3], tlo)
            q = self._rest(centre)
            v = [q[a] - p[a] for a in range(3)]
            if keep & (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] < site_reach * site_reach):
                state = self._site_member(tile, kept, q, self._class(_open(u_class)), p, d, tol, visit, state, tag)
            kept += dr.select(keep, 1, 0)
            i += 1
        return state

    def _rest(self, centre):
        """A candidate's rest position in scene units: the cloud's transform of its centre."""
        m = self.to_scene
        return [m[r][0] * centre[0] + m[r][1] * centre[1] + m[r][2] * centre[2] + m[r][3] for r in range(3)]

    def _site_member(self, tile, kept, q, code, p, d, tol, visit, state, tag):
        """``visit`` at one kept candidate (rest position ``q``, class ``code``) with its membership of the site."""
        F = mi.Float64
        # The drift only where the rest position is within its bound of the site.
        # (A member lies within its R, the base tolerance and ``tol`` of p.)
        near_p = tol + (tag[1] if tag is not None else tol)
        reach, q = self._placed(True, q, code,
                                lambda x, r_d: sum((x[a] - p[a]) ** 2 for a in range(3)) < (r_d + near_p) ** 2)
        v = [F(mi.Float(q[a])) - p[a] for a in range(3)]
        along = v[0] * d[0] + v[1] * d[1] + v[2] * d[2]
        w = [v[a] - along * d[a] for a in range(3)]
        rim = reach + (tag[1] if tag is not None else tol)  # the flight's rounding across, too
        member = (dr.abs(along) <= tol) & (w[0] * w[0] + w[1] * w[1] + w[2] * w[2] < rim * rim)
        if tag is not None:
            limit = (1 << self.index_bits) - 1
            key = ((mi.UInt64(tile) << self.index_bits) | mi.UInt64(dr.minimum(kept, limit))) + 1
            # The search kept the picked grain's site inside its ball: its shift is also within R.
            agree = tags_agree(tag[0], grain_hash(fold_key(key)), mi.Float(reach), tag[2], self.tag_thresholds)
            member &= (agree & (dr.abs(along) <= tag[1] + reach)) | (dr.abs(along) <= tag[1])
        tau = dr.gather(mi.Float, self._tau, code, member)
        b = dr.gather(mi.UInt32, self._bin, code, member)
        return visit(tau, b, member, state)

    @dr.syntax
    def _placed(self, keep, q, code, near):
        """A candidate's inclusion radius (Float64) and scene position: its rest position ``q`` (``_rest``), moved
        by the drift where ``near(rest position, reach + the drift's bound)`` (a mask) says the drift can matter."""
        reach = mi.Float64(dr.gather(mi.Float, self._reach, code))
        if self.motion is not None:
            if keep & near(q, reach + DRIFT_PER_TURBULENCE * self.motion[1]):
                q = self._moved(q)
        return reach, q

    @staticmethod
    def _meets(p, reach, o, d, t0, t1):
        """Whether the ray passes within ``reach`` of ``p`` with the projection in [t0, t1)."""
        v = [p[a] - o[a] for a in range(3)]
        t = v[0] * d[0] + v[1] * d[1] + v[2] * d[2]
        q = [v[a] - t * d[a] for a in range(3)]
        return (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] < reach * reach) & (t >= t0) & (t < t1), t


def _rays(origin, direction, t0, t1):
    """Rays as Float64 triples and segment ends of one width."""
    F = mi.Float64
    o = [F(origin[a]) for a in range(3)]
    d = [F(direction[a]) for a in range(3)]
    n = max(dr.width(o[0]), dr.width(d[0]), dr.width(F(t0)), dr.width(F(t1)))
    return [x + dr.zeros(F, n) for x in o], [x + dr.zeros(F, n) for x in d], F(t0) + dr.zeros(F, n), \
        F(t1) + dr.zeros(F, n)


def _face(c, at, per_t, inv_p):
    """``drjit_walk.face`` in double precision."""
    return face(c, at, per_t, inv_p, mi.Float64)


def _advance(c, t_next, step, at, per_t, inv_p, t_out):
    """One DDA step along the axis whose face comes first: (the three cells, the three next faces, the axis,
    whether the segment goes on past that face)."""
    axis = dr.select(t_next[2] < dr.minimum(t_next[0], t_next[1]), 2, dr.select(t_next[1] < t_next[0], 1, 0))
    go = dr.minimum(dr.minimum(t_next[0], t_next[1]), t_next[2]) < t_out
    c = [dr.select(go & (axis == a), c[a] + step[a], c[a]) for a in range(3)]
    t_next = [dr.select(go & (axis == a), _face(c[a], at[a], per_t[a], inv_p[a]), t_next[a]) for a in range(3)]
    return (*c, *t_next, axis, go)
