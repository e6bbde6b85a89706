"""The walk of the particle grid in Dr.Jit-typed code (issue 46): optical depth along a ray and exact free
flights to the first grain interaction, for a wavefront of rays, in the current Mitsuba variant's JIT types
(``llvm_ad_*`` and ``cuda_ad_*``: a CUDA kernel cannot call the Rust core); the medium plugin's ``kernel =
drjit`` (``plugins/drjit_medium.py``) walks stored grains with it. The physics is the Rust core's (``rust/motes-core/src/space/grid/``);
this module only reads a built grid's grains as flat arrays (``ParticleGrid.flat_arrays`` or
``DiscreteMedium.flat_arrays``, ``rust/motes-core/src/space/grid/flat.rs``) and walks them:

* grain i contributes to a ray when the ray passes within R_i = r_c + r_i of its centre and the projection
  t_i of the centre on the ray lies in the segment [0, t_max); it adds its disk's optical depth tau_i (the
  paper's Eq. 18 normalised per disk, ``rust/motes-core/src/space/grid/mod.rs``). The optical depth of a
  segment is the sum; its transmittance exp(-tau).
* a free flight interacts at grain i with probability 1 - exp(-tau_i), independently of the others, and
  stops at the first grain (smallest t_i) that interacts: P(grain j) = prod_{t_i < t_j} exp(-tau_i) (1 -
  exp(-tau_j)), the distribution the Rust walk samples by inversion of one uniform along the ordered grains
  (``ParticleGrid::free_flight``). Here each grain draws its own uniform from a hash of the ray's seed and
  the grain's position in the flat arrays, so that the walk need not visit the grains in t order: the same
  distribution, not the same sample for the same ``u``. The seed is hashed once per ray (TEA, 8 rounds) into
  two keys; each grain's 64 bits are two 32-bit mixes (``_mix``) of a key and its position, a dozen integer
  operations where TEA per grain took some 130.

The walk (per size class of the grid, each with its own cells, at least as wide as the class's largest
inclusion radius): a 3D-DDA over the cells the ray crosses (Amanatides & Woo), and per step the cells of the
3x3x3 block around the step's cell that no earlier step tested: the whole block at the first step, then the
3x3 slab each move adds on the far side (a DDA step moves along one axis, and monotonically). Every grain
whose ball reaches the ray is in such a block, and in exactly one slab: a grain that straddles cells is
stored once, in its centre's cell, and tested once. Of a step's cells, only the layers (per axis) the
segment comes within the class's reach of, over the part of it that is near all three ranges, are read
(the Rust walk's ``Near``), a row (a run of cells along x, contiguous in the arrays) at a time, in one loop
over the step's rows and their grains: an iteration reads the next row where a lane's row is done, else tests
one grain of it, so that lanes with rows of different lengths keep busy. On the CPU the gathers are most of
the walk's time (AVX2 gathers: ``bench_drjit_walk.py``), hence three choices. In the lattice layout the
cells' starts follow the grains' words in one array, and an iteration makes one pair of gathers: a row's two
starts, or a grain's two words (a row read and a grain test in one iteration took four gathers). A grain's
own R (a gather of its code's) is read only where its centre lies within the class's reach of the ray, and
the rest of the test, with the draw and what a hit costs, is a symbolic branch that a SIMD packet without
such a grain skips. (A single loop over steps, rows and grains, so that no step waits for the packet's lane
with most grains, was slower: each iteration then carries the step's work too.) Once a step is done every grain with
t_i before its exit has been tested, so a free flight stops there once it has interacted before that exit, and the
next class walks only up to that interaction (the classes are independent).

Precision: ``double=False`` walks in the variant's ``Float`` (single precision: the exact test runs from an
origin moved to each step's entry, so that its error is a few 1e-7 of the cell and of the coordinates'
scale; grains within that of their disk's edge or of the segment's ends may fall either way),
``double=True`` in ``Float64`` (the Rust core's precision, for tests). Optical depths are summed in the
walk's precision (single: a relative rounding of ~1e-7 per grain met; a ``Float64`` sum made the single
walk 25 % slower on ``bench_drjit_walk.py``'s 1e5 grains). A free flight's interaction probabilities
1 - exp(-tau_i) are single precision without cancellation (a series for small tau_i: relative error ~1e-7,
tau_i's own rounding), compared in ``Float64`` with 64-bit uniforms (a grain of tau_i ~ 1e-9 keeps its
probability).

Layout (``DrJitGrid.layout``, ``bytes_per_grain``). ``lattice`` where every centre lies on its class's lattice
of ``LATTICE_PER_CELL`` steps per cell edge (compact storage's grains: the core's quantised slots, ``slots.rs``)
and a class has at most 2^16 distinct (R_i, tau_i, bin): per grain 8 bytes, two u32 words holding its lattice
coordinates modulo 2^16 and its code (x | y << 16, z | code << 16), and per class a table of (R, tau, bin) by
code. A row of cells x0..x1 at (y, z) holds centres within [1, 4) cells of the corner (x0 - 1, y - 1, z - 1),
so that the wrapped difference of the u16s is the exact offset from it (the core's reading). Else
``spheres``: per grain centre and R (f32x4), tau (f32) and bin (u32), 24 bytes. Either way 4 bytes a cell
(its first grain; ``start_of``), and the indices the grid reports (4 bytes a grain) only once a free flight asks for
them.

``DrJitGrid(grid)``: ``grid`` is a ``motes.ParticleGrid`` or ``motes.DiscreteMedium`` (or their
``motes._motes`` cores), or the dict their ``flat_arrays`` return; ``layout`` is ``auto`` (lattice where it
holds the grains exactly, else spheres), ``lattice`` (an error where it cannot) or ``spheres``. The kernels
run with symbolic loops whatever the flag says (the plugins' evaluated mode would run each loop iteration as
a kernel).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from . import _motes

#: TEA rounds of a free flight's keys (``mi.sample_tea_32(seed, constant)``, once per ray; module docs).
TEA_ROUNDS = 8
#: Margin of the class box the DDA clips to, and of the rows' reach, in cells: rounding of the cell
#: coordinates must not drop a grain the exact test accepts (a wider margin only tests a few more).
CELL_MARGIN = 1e-3
#: Relative margin of the rows' reach (see ``CELL_MARGIN``).
REACH_MARGIN = 1e-4
#: Relative growth of a grain's ball in ``exclude_origin``: a ray leaving a site at the float32 projection of
#: a grain's centre must not meet that grain again where rounding puts the site a hair outside its ball (the
#: medium plugin's tag search keeps a site inside its grain's ball, R itself: this margin absorbs the walk's
#: own rounding of the same distance, ~1e-7 relative where the ray starts in the class's box).
EXCLUDE_MARGIN = 1e-4
_NONE = 0xFFFFFFFF
#: Bits of the origin tag at most (``grain_tag``, ``origin_tag``; the medium plugin's "Parent exclusion"); a small
#: ball far from the origin gets fewer (``tag_bits``).
TAG_BITS = 6
TAG_MASK = (1 << TAG_BITS) - 1
#: The one origin tag no grain has (grains' tags are 0 .. ``FIELD_TAG`` - 1): the medium plugin moves a field
#: event to a point of this tag, so that the rays leaving it skip no grain and its site admits none by tag. Its
#: low b bits are all ones, which no grain's b-bit tag is (``tags_agree``), so it serves every ``tag_bits``.
FIELD_TAG = TAG_MASK
#: ``tag_bits``: all ``TAG_BITS`` wherever x = e(R) - e(m) >= ``TAG_FULL`` (e: a float's binary exponent; R a
#: ball's inclusion radius, m the largest magnitude of a point's coordinates): the ball's chord then holds at least
#: ~2^(x + 24) >= 8192 distinct float points along a central hit, and 6 bits miss their tag at less than ~1e-4 of
#: the sites (grazing hits dominate: ~2 (64 / 2^(x + 24))^2). Every scene measured so far lies there.
TAG_FULL = -11
#: Lattice steps per cell edge of the lattice layout (module docs, "Layout"): the core's compact storage's
#: (``LATTICE_PER_CELL`` in ``rust/motes-core/src/space/grid/slots.rs``).
LATTICE_PER_CELL = 1 << 14


def _arrays_of(grid, channel: int) -> dict:
    if isinstance(grid, dict):
        return grid
    inner = getattr(grid, "_grid", getattr(grid, "_core", grid))  # motes.ParticleGrid, motes.DiscreteMedium
    if isinstance(inner, _motes.ParticleGrid):
        return inner.flat_arrays(channel)
    if isinstance(inner, _motes.DiscreteMedium):  # grey: one channel
        out = inner.flat_arrays()
        if out is None:
            raise ValueError("the medium stores no grains to walk (a procedural cloud, or every size class "
                             "continuous)")
        return out
    raise TypeError(f"motes.drjit_walk walks a ParticleGrid, a DiscreteMedium or their flat arrays, not {type(grid)}")


def _lattice_layout(a: dict, spheres: np.ndarray):
    """The lattice layout of flat arrays ``a`` (module docs, "Layout"), or None where it cannot hold them exactly
    (a centre off its class's lattice, or more than 2^16 (R, tau, bin) codes in a class): (per grain two u32
    words, per class its first code, per code R, tau and bin (None without bins))."""
    n = spheres.shape[0]
    if n == 0 or 2 * n + len(a["start"]) >= 2**32:  # grains' words and cells' starts index one u32 array
        return None
    lo = np.asarray(a["class_lo"], dtype=np.float64).reshape(-1, 3)
    cell = np.asarray(a["class_cell"], dtype=np.float64)
    bounds = np.asarray(a["class_grains"], dtype=np.int64)
    tau = np.ascontiguousarray(a["tau"], dtype=np.float32)
    bins = np.ascontiguousarray(a["bin"], dtype=np.uint32) if "bin" in a else np.zeros(n, dtype=np.uint32)
    words = np.empty((n, 2), dtype=np.uint32)
    code_off, reach_k, tau_k, bin_k, total = [], [], [], [], 0
    for k in range(cell.size):
        g0, g1 = int(bounds[k]), int(bounds[k + 1])
        code_off.append(total)
        if g1 == g0:
            continue
        step = cell[k] / LATTICE_PER_CELL
        lattice = np.round((spheres[g0:g1, :3].astype(np.float64) - lo[k]) / step)
        if not np.array_equal((lo[k] + lattice * step).astype(np.float32), spheres[g0:g1, :3]):
            return None
        key = (spheres[g0:g1, 3].view(np.uint32).astype(np.uint64) << np.uint64(32)) | tau[g0:g1].view(np.uint32)
        key = np.stack([key, bins[g0:g1].astype(np.uint64)], axis=1)
        codes, which = np.unique(key, axis=0, return_inverse=True)
        if codes.shape[0] > 1 << 16:
            return None
        q = lattice.astype(np.int64) & 0xFFFF
        words[g0:g1, 0] = q[:, 0] | (q[:, 1] << 16)
        words[g0:g1, 1] = q[:, 2] | (which.ravel().astype(np.int64) << 16)
        reach_k.append((codes[:, 0] >> np.uint64(32)).astype(np.uint32).view(np.float32))
        tau_k.append((codes[:, 0] & np.uint64(0xFFFFFFFF)).astype(np.uint32).view(np.float32))
        bin_k.append(codes[:, 1].astype(np.uint32))
        total += codes.shape[0]
    return (words, np.asarray(code_off, dtype=np.uint32), np.concatenate(reach_k), np.concatenate(tau_k),
            np.concatenate(bin_k) if "bin" in a else None)


_GOLDEN = 0x9E3779B9
_GOLDEN2 = 0x85EBCA6B


def _mix(x):
    """A 32-bit integer hash with full avalanche (C. Wellons' "lowbias32"): a grain's draw is ``_mix(key0 +
    position * _GOLDEN)`` and ``_mix(key1 ^ position * _GOLDEN2)`` (module docs)."""
    x = x ^ (x >> 16)
    x = x * 0x7FEB352D
    x = x ^ (x >> 15)
    x = x * 0x846CA68B
    return x ^ (x >> 16)


def grain_hash(ident):
    """A 32-bit hash (``mi.UInt32``) of a grain's identity (a stored grid: its position in the flat arrays; a
    procedural cloud: its 64-bit key folded to 32 bits, ``fold_key``): its tag's source (``tags_agree``)."""
    return _mix(mi.UInt32(ident) ^ 0x5BD1E995)


def grain_tag(ident):
    """A grain's ``TAG_BITS``-bit tag (``mi.UInt32``, 0 .. ``FIELD_TAG`` - 1, uniform to 1e-8)."""
    return grain_hash(ident) % FIELD_TAG


def origin_hash(x, y, z):
    """A 32-bit hash (``mi.UInt32``) of a point's three float32 coordinates' bits: its tag's source."""
    b = [dr.reinterpret_array(mi.UInt32, mi.Float(c)) for c in (x, y, z)]
    return _mix(b[2] ^ _mix(b[1] ^ _mix(b[0] + _GOLDEN)))


def origin_tag(x, y, z):
    """A point's ``TAG_BITS``-bit tag (``mi.UInt32``). A ray skips a grain whose ball holds its origin only where
    their tags agree (``tags_agree``; the medium plugin's docs)."""
    return origin_hash(x, y, z) & TAG_MASK


def largest(x, y, z):
    """The largest magnitude of a point's coordinates (``mi.Float``): the scale of its float32 ulp."""
    return dr.maximum(dr.maximum(dr.abs(mi.Float(x)), dr.abs(mi.Float(y))), dr.abs(mi.Float(z)))


def _exponent(x):
    """The binary exponent of float32 ``x`` (``mi.Int32``; 0 gives -127, inf and NaN 128)."""
    return mi.Int32((dr.reinterpret_array(mi.UInt32, mi.Float(x)) >> 23) & 0xFF) - 127


def point_exponent(x, y, z):
    """The binary exponent of a point's ``largest`` coordinate (``mi.Int32``): what its tag's width reads of it
    (``tag_bits``), computed once per point."""
    return _exponent(largest(x, y, z))


def tag_thresholds(holders: float) -> tuple:
    """The tag's bits as a function of x = e(R) - e(m) (``TAG_FULL``) for a cloud where ``holders`` other balls
    hold a site on average: (X_2, ..., X_6), b = 1 + the number of X_k <= x. Below ``TAG_FULL`` the ball's chord
    holds only N ~ 2^(x + 24) distinct float points along a central hit (N sqrt(1 - s^2) at impact s R), too few to
    find 6 bits in: b minimises the grains treated wrongly per site, the own grain's tag not found (the site keeps
    its point, and the rays leaving it may meet the grain again), E_s[(1 - 2^-b)^(N sqrt(1 - s^2))], plus the other
    balls holding a point skipped though they should not be, ``holders`` (1 / (2^b - 1) + 2^-b) (at a site, and
    at any other origin inside a ball). Measured with ``scripts/bench/bench_drjit_dense.py --offset``."""
    # Below x = -24 a ball holds less than a float point across: 1 bit there whatever the cloud.
    x = np.arange(-24, TAG_FULL)[:, None, None]
    bits = np.arange(1, TAG_BITS + 1)[None, :, None]
    chord = np.sqrt(1 - (np.arange(512) + 0.5) / 512)[None, None, :]  # s^2 uniform over the disk
    miss = ((1 - 2.0**-bits) ** (2.0 ** (x + 24) * chord)).mean(axis=2)
    holders = float(holders) if np.isfinite(holders) else 1e30  # NaN or inf: as dense as can be (6 bits)
    skip = max(holders, 0.0) * (1 / (2.0**bits - 1) + 2.0**-bits)[:, :, 0]
    best = 1 + np.argmin(miss + skip, axis=1)
    best = np.minimum.accumulate(best[::-1])[::-1]  # nondecreasing in x: at most the best of every larger x
    xs = x[:, 0, 0]
    return tuple(int(xs[best >= k][0]) if np.any(best >= k) else TAG_FULL for k in range(2, TAG_BITS + 1))


def _exponent_host(x: float) -> int:
    """``_exponent`` on the host: the binary exponent of float32 ``x``."""
    return int((np.float32(x).view(np.uint32) >> 23) & 0xFF) - 127


def cloud_tag_thresholds(holders: float, r_min: float, m_max: float):
    """A cloud's ``tag_thresholds``, or None where every point inside any of its balls gets all ``TAG_BITS`` (the
    smallest inclusion radius ``r_min`` against ``m_max``, a bound on the coordinates' magnitudes inside a ball):
    ``tags_agree`` then reads the 6-bit tags alone (every shipped scene), as cheap as before the widths existed."""
    thresholds = tag_thresholds(holders)
    m_max = float(np.nextafter(np.float32(abs(m_max)), np.float32(np.inf)))
    if _exponent_host(r_min) - _exponent_host(m_max) >= thresholds[-1]:
        return None
    return thresholds


def ball_holders(radius: np.ndarray, volume: float) -> float:
    """The mean number of balls (inclusion radii ``radius``, scene units) holding a point of a cloud of
    ``volume``: their volumes' sum over it (``tag_thresholds``; a clumped cloud holds more at its sites)."""
    r = np.asarray(radius, dtype=np.float64)
    return float(np.sum(4 / 3 * np.pi * r**3) / max(float(volume), 1e-300))


def tag_bits(radius, m_exp, thresholds):
    """The tag's bits (``mi.UInt32``, 1 .. ``TAG_BITS``) for a grain of inclusion radius ``radius`` at a point whose
    largest coordinate's exponent is ``m_exp`` (``point_exponent``), ``thresholds`` its cloud's ``tag_thresholds``:
    6 wherever R / m >= ~2^-11 (``TAG_FULL``), fewer in a ball of a few ulps, where a tag of 6 bits could not be
    found. A function of R and of the point alone (their float32 exponents: no rounding can change it), so that the
    search that moves a site (at its candidate point) and the rays leaving it (at their origin) agree."""
    if thresholds is None:  # ``cloud_tag_thresholds``: no ball of the cloud is a few ulps wide
        return mi.UInt32(TAG_BITS) + dr.zeros(mi.UInt32, dr.width(radius))
    x = _exponent(radius) - mi.Int32(m_exp)
    b = mi.UInt32(1)
    for xk in thresholds:
        b += dr.select(x >= xk, 1, 0)
    return b


def tags_agree(o_hash, g_hash, radius, m_exp, thresholds):
    """Whether a point (its ``origin_hash`` ``o_hash`` and ``point_exponent`` ``m_exp``) carries the tag of a grain
    (its ``grain_hash`` ``g_hash`` and inclusion radius ``radius``) in a cloud of ``thresholds``: with b =
    ``tag_bits``, the point's low b bits equal the grain's b-bit tag, 0 .. 2^b - 2 (all ones is ``FIELD_TAG``'s):
    at b = ``TAG_BITS`` ``grain_tag`` (so ``origin_tag == grain_tag``), below it the hash's top bits scaled to
    0 .. 2^b - 2 (a multiplication, where a modulo by a varying 2^b - 1 would be a division on every test).
    ``thresholds`` None (``cloud_tag_thresholds``: 6 bits wherever a point lies in a ball): the 6-bit test alone."""
    if thresholds is None:
        return (mi.UInt32(o_hash) & TAG_MASK) == mi.UInt32(g_hash) % FIELD_TAG
    bits = tag_bits(radius, m_exp, thresholds)
    mask = (mi.UInt32(1) << bits) - 1
    g_hash = mi.UInt32(g_hash)
    narrow = mi.UInt32((mi.UInt64(g_hash) * mi.UInt64(mask)) >> 32)
    return (mi.UInt32(o_hash) & mask) == dr.select(bits == TAG_BITS, g_hash % FIELD_TAG, narrow)


def fold_key(key):
    """A procedural grain's 64-bit key folded to the 32 bits ``grain_tag`` hashes."""
    return mi.UInt32(key & 0xFFFFFFFF) ^ mi.UInt32(key >> 32)


def one_minus_exp(x):
    """1 - exp(-x) without its cancellation for small x: below 0.05 its series, to x^5 in single precision
    (relative error ~1e-7), to x^6 in double (< 1e-12), else exp."""
    inner = x * (1 / 120) if dr.type_v(x) != dr.VarType.Float64 else x * (1 / 120 - x * (1 / 720))
    s = x * (1 - x * (1 / 2 - x * (1 / 6 - x * (1 / 24 - inner))))
    return dr.select(x < 0.05, s, 1 - dr.exp(-x))


def face(c, at, per_t, inv_p, F):
    """t of the face a ray leaves cell layer ``c`` by, in the walk's float type ``F`` (inf along an axis it does
    not move on): ``at`` its cell coordinate at t = 0, ``per_t`` cells per unit t, ``inv_p`` its inverse."""
    return dr.select(per_t > 0, (F(c + 1) - at) * inv_p, dr.select(per_t < 0, (F(c) - at) * inv_p, dr.inf))


def near(at, per_t, inv_p, m0, m1, reach, t0, t1, F):
    """The part of [t0, t1] where a ray's coordinate ``at + t per_t`` (cells) lies within ``reach`` of layers
    ``m0..m1`` (a slab test, in the float type ``F``): (ta, tb), empty when ta > tb."""
    u0 = (F(m0) - reach - at) * inv_p
    u1 = (F(m1 + 1) + reach - at) * inv_p
    flat = per_t == 0
    inside = (at >= F(m0) - reach) & (at <= F(m1 + 1) + reach)
    lo = dr.select(flat, dr.select(inside, -dr.inf, dr.inf), dr.minimum(u0, u1))
    hi = dr.select(flat, dr.select(inside, dr.inf, -dr.inf), dr.maximum(u0, u1))
    return dr.maximum(t0, lo), dr.minimum(t1, hi)


class DrJitGrid:
    """A grid's grains uploaded once as the current variant's JIT arrays, walked by ``optical_depth``,
    ``transmittance`` and ``sample_free_flight`` (module docs)."""

    def __init__(self, grid, *, channel: int = 0, double: bool = False, layout: str = "auto"):
        if not mi.variant() or not mi.variant().startswith(("llvm_", "cuda_")):
            raise RuntimeError(f"motes.drjit_walk needs a JIT variant (llvm_* or cuda_*), not {mi.variant()!r}")
        a = _arrays_of(grid, channel)
        self.double = bool(double)
        self.F = mi.Float64 if self.double else mi.Float
        spheres = np.ascontiguousarray(a["spheres"], dtype=np.float32).reshape(-1, 4)
        self.count = int(spheres.shape[0])
        # The origin tag's bits where balls are a few ulps wide (``tag_thresholds``): the balls holding a point.
        if self.count:
            side = spheres[:, :3].max(axis=0) - spheres[:, :3].min(axis=0) + 2 * float(spheres[:, 3].max())
            self.holders = ball_holders(spheres[:, 3], float(np.prod(side.astype(np.float64))))
            m_max = float(np.abs(spheres[:, :3]).max()) + float(spheres[:, 3].max())
            self.tag_thresholds = cloud_tag_thresholds(self.holders, float(spheres[:, 3].min()), m_max)
        else:
            self.holders = 0.0
            self.tag_thresholds = None
        self.classes = int(len(a["class_cell"]))
        self.cells = int(len(a["start"]))
        self.bin = np.asarray(a["bin"]) if "bin" in a else None
        # The grains (module docs, "Layout"), and the index the grid reports for each, uploaded at the first
        # free flight that asks for it (``_index``).
        self._index_host = np.ascontiguousarray(a["index"], dtype=np.uint32)
        self._index_dev = None
        lattice = _lattice_layout(a, spheres) if layout in ("auto", "lattice") else None
        if layout == "lattice" and lattice is None:
            raise ValueError("DrJitGrid: layout = lattice needs every centre on its class's lattice and at most "
                             f"{1 << 16} (R, tau, bin) codes per class")
        self.layout = "lattice" if lattice is not None else "spheres"
        if lattice is not None:
            words, code_off, reach, tau, bins = lattice
            # The grains' words, then the cells' starts (at ``_s_off``): one array, so that one gather reads a
            # grain's word where a lane tests a grain and a cell's start where it reads a row (``_walk``).
            cells = [words.ravel(), np.ascontiguousarray(a["start"], dtype=np.uint32)]
            if (words.size + cells[1].size) % 2:  # a grain's words gather as a pair: an even length
                cells.append(np.zeros(1, dtype=np.uint32))
            self._cells = mi.UInt32(np.concatenate(cells))
            self._s_off = int(words.size)
            self._code_off = mi.UInt32(code_off)
            self._reach_of = mi.Float(reach)
            self._tau = mi.Float(tau)
            self._bin = mi.UInt32(bins) if bins is not None else None
            self._table_bytes = 4 * (code_off.size + reach.size + tau.size + (0 if bins is None else bins.size))
            self._grain_bytes = 8
        else:
            self._spheres = mi.Float(spheres.ravel())
            self._cells = mi.UInt32(np.ascontiguousarray(a["start"], dtype=np.uint32))
            self._s_off = 0
            self._tau = mi.Float(np.ascontiguousarray(a["tau"], dtype=np.float32))
            self._bin = mi.UInt32(np.ascontiguousarray(self.bin, dtype=np.uint32)) if self.bin is not None else None
            self._table_bytes = 0
            self._grain_bytes = 16 + 4 + (4 if self.bin is not None else 0)
        # Per class: corner, 1 / cell, cells per axis, reach in cells (with margins), first cell start.
        cell = np.asarray(a["class_cell"], dtype=np.float64)
        self._cell = self.F(cell)
        self._lo = self.F(np.ascontiguousarray(np.asarray(a["class_lo"], dtype=np.float64).ravel()))
        self._inv_cell = self.F(1.0 / cell)
        self._dims = mi.Int32(np.ascontiguousarray(np.asarray(a["class_dims"]).ravel().astype(np.int32)))
        reach_cells = np.asarray(a["class_reach"], dtype=np.float64) / cell
        self._reach = self.F(reach_cells * (1 + REACH_MARGIN) + CELL_MARGIN)
        self._class_start = mi.UInt32(np.asarray(a["class_start"]).astype(np.uint32))
        self._n_classes = dr.opaque(mi.UInt32, self.classes)

    @property
    def bytes_per_grain(self) -> float:
        """Bytes the uploaded arrays hold per grain, the cell starts (4 B a cell, ``cells``) aside: the grains,
        their tables shared out over them, and the reported indices once a free flight has asked for them."""
        index = 4 if self._index_dev is not None else 0
        return self._grain_bytes + index + self._table_bytes / max(self.count, 1)

    @property
    def _index(self):
        if self._index_dev is None:
            self._index_dev = mi.UInt32(self._index_host)
        return self._index_dev

    def frame(self, k):
        """What ``grain`` reads of class ``k`` (gathered once per class, not per grain)."""
        if self.layout == "spheres":
            return None
        F = self.F
        return ([dr.gather(F, self._lo, 3 * k + a) for a in range(3)], dr.gather(F, self._cell, k),
                dr.gather(mi.UInt32, self._code_off, k))

    def grain(self, g, frame, x0, y, z, active, radius=True):
        """Grain ``g`` of the class of ``frame`` (``frame(k)``), read from a row of cells that starts at cell
        (x0, y, z) (the row holds it): (centre [x, y, z] in ``self.F``, inclusion radius R, its entry in the
        per-code tables (``tau_of``, ``bin_of``, ``radius_of``)). ``radius=False``: R is None where reading it
        takes a gather of its own (the lattice layout: ``radius_of`` reads it once the centre is near enough)."""
        F, U = self.F, mi.UInt32
        if self.layout == "spheres":
            s = dr.gather(mi.Vector4f, self._spheres, g, active)
            return [F(s[0]), F(s[1]), F(s[2])], F(s[3]), g
        w = dr.gather(mi.Vector2u, self._cells, g, active)
        centre, tid = self.decode(w[0], w[1], frame, x0, y, z)
        return centre, self.radius_of(tid, active) if radius else None, tid

    def decode(self, w0, w1, frame, x0, y, z):
        """(centre, table entry) of a grain of the lattice layout from its two words (``grain``)."""
        F, U = self.F, mi.UInt32
        lo, cell, code_off = frame
        q = (w0 & 0xFFFF, w0 >> 16, w1 & 0xFFFF)
        centre = []
        for a, c in enumerate((x0, y, z)):
            # The offset from the corner one cell below the row's (module docs, "Layout"), in u32 arithmetic.
            off = (q[a] + LATTICE_PER_CELL - U(c) * LATTICE_PER_CELL) & 0xFFFF
            centre.append(lo[a] + (F(c - 1) + F(off) * (1.0 / LATTICE_PER_CELL)) * cell)
        return centre, code_off + (w1 >> 16)

    def radius_of(self, tid, active):
        """The inclusion radius R (``self.F``) of the grains of table entry ``tid`` (``grain``; lattice layout)."""
        return self.F(dr.gather(mi.Float, self._reach_of, tid, active))

    def start_of(self, cell, active):
        """The position of cell ``cell``'s first grain in the grain arrays (``mi.UInt32``; a cell of a class at
        its class's start plus (z dims_y + y) dims_x + x; the grid's last cell plus one: the number of grains)."""
        return dr.gather(mi.UInt32, self._cells, cell + self._s_off, active)

    def tau_of(self, tid, active):
        """The optical depth (``mi.Float``) of the grains of table entry ``tid`` (``grain``)."""
        return dr.gather(mi.Float, self._tau, tid, active)

    def bin_of(self, tid, active):
        """The size bin (``mi.UInt32``) of the grains of table entry ``tid`` (``grain``)."""
        return dr.gather(mi.UInt32, self._bin, tid, active)

    # ------------------------------------------------------------------------------------------ queries

    def optical_depth(self, origin, direction, tmax):
        """Optical depth (``self.F``) of the segments [0, tmax) of the rays ``origin + t direction``
        (t in units of the normalised direction; tmax may be 0 or inf)."""
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            tau, _, _ = self._walk(origin, direction, tmax, None)
        return tau

    def transmittance(self, origin, direction, tmax):
        """exp(-optical depth) of the segments [0, tmax) (``self.F``): what the Rust core's
        ``ParticleGrid.optical_depth`` gives as exp(-tau)."""
        return dr.exp(-self.optical_depth(origin, direction, tmax))

    def sample_free_flight(self, origin, direction, tmax, u, *, exclude_origin=False, want_index=True,
                           tagged=False, want_grain=False, want_ball=False):
        """Exact free flights on [0, tmax): ``(t, index, valid)``: the distance to the first grain that
        interacts (``self.F``; inf where none), the index the grid reports for it (``mi.UInt32``; 2^32 - 1
        where none) and whether there is one. ``u``: per ray a uniform ``mi.Float`` in [0, 1) (its bits seed
        the grains' draws) or a ``mi.UInt32`` seed (module docs). ``exclude_origin`` (a bool, or per ray a
        ``mi.Bool``): grains whose ball (radius R_i, grown by ``EXCLUDE_MARGIN``) holds the ray's origin are
        skipped (the medium plugin's stateless "parent" exclusion: a ray leaving a site skips its grains).
        ``tagged`` (with ``exclude_origin``): only those of such grains whose tag the origin carries
        (``tags_agree``) are skipped (the medium plugin's origin tag). ``want_index=False``: no index
        (None; the indices are then not uploaded). ``want_grain``: a further value, the grain's position in the
        flat arrays (2^32 - 1 where none). ``want_ball``: a further value, the grain's ball as the walk read it,
        (centre [x, y, z], R) in ``self.F`` (0 where none): the medium plugin's tag search keeps a site inside
        it."""
        if isinstance(u, mi.UInt32):
            seed = u
        else:
            seed = dr.reinterpret_array(mi.UInt32, mi.Float(u))
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            _, t, g, *ball = self._walk(origin, direction, tmax, seed, exclude_origin, tagged, ball=want_ball)
        valid = g != _NONE
        index = dr.select(valid, dr.gather(mi.UInt32, self._index, g, valid), _NONE) if want_index else None
        out = (dr.select(valid, t, dr.inf), index, valid)
        return out + ((g,) if want_grain else ()) + tuple(ball)

    # ------------------------------------------------------------------------------------------ the walk

    def _rays(self, origin, direction, tmax):
        F = self.F
        o = [F(origin[a]) for a in range(3)]
        d = [F(direction[a]) for a in range(3)]
        norm = dr.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        d = [x / norm for x in d]
        n = max(dr.width(o[0]), dr.width(d[0]), dr.width(F(tmax)))
        tmax = F(tmax) + dr.zeros(F, n)
        return o, d, tmax, n

    @dr.syntax
    def _walk(self, origin, direction, tmax, seed, exclude_origin=False, tagged=False, ball=False):
        """The walk of every class (module docs): (optical depth, first interaction's t, its grain's position
        or 2^32 - 1); a free flight where ``seed`` is given, else the optical depth alone. ``ball`` (a free
        flight): a fourth value, the interacting grain's (centre [x, y, z], R) as the walk read them."""
        F, I, U = self.F, mi.Int32, mi.UInt32
        o, d, best_t, n = self._rays(origin, direction, tmax)
        flight = seed is not None
        excluding = exclude_origin is not False
        if excluding:
            exclude_origin = mi.Bool(exclude_origin) | dr.zeros(mi.Bool, n)
        tagged = excluding and bool(tagged)
        # The origin's tag (``tags_agree``): its hash, and the exponent its ulp scales with.
        o_hash = origin_hash(origin[0], origin[1], origin[2]) + dr.zeros(U, n) if tagged else None
        o_m = point_exponent(origin[0], origin[1], origin[2]) + dr.zeros(mi.Int32, n) if tagged else None
        thresholds = self.tag_thresholds
        # A free flight's keys: a hash of the ray's seed, which each grain's draw mixes with its position.
        key0, key1 = mi.sample_tea_32(U(seed) + dr.zeros(U, n), U(0x2545F491), TEA_ROUNDS) if flight else (0, 0)
        tau = dr.zeros(F, n)
        best_g = dr.full(U, _NONE, n)
        # The interacting grain's ball (``ball``), kept where it interacts: its centre and R as read here.
        bx, by, bz, br = (dr.zeros(F, n) for _ in range(4))
        k = dr.zeros(U, n)
        lattice = self.layout == "lattice"
        s_off = self._s_off
        while k < self._n_classes:
            # The class's frame, the ray in its cell coordinates x(t) = at + t per_t.
            inv_cell = dr.gather(F, self._inv_cell, k)
            reach = dr.gather(F, self._reach, k)
            reach_w2 = dr.square(reach / inv_cell)  # the class's reach (with margins) squared, scene units
            soff = dr.gather(U, self._class_start, k)
            frame = self.frame(k)
            dims = [dr.gather(I, self._dims, 3 * k + a) for a in range(3)]
            at = [(o[a] - dr.gather(F, self._lo, 3 * k + a)) * inv_cell for a in range(3)]
            per_t = [d[a] * inv_cell for a in range(3)]
            inv_p = [1 / p for p in per_t]
            # The segment inside the class's box (grown by CELL_MARGIN cells), as a slab test.
            t_in, t_out = dr.zeros(F, n), F(best_t)
            for a in range(3):
                t_in, t_out = self._near(at[a], per_t[a], inv_p[a], 0, dims[a] - 1, CELL_MARGIN, t_in, t_out)
            active = t_in < t_out
            # The DDA: the cell at entry, the direction of its steps and the t of each axis' next face.
            c, step, t_next = [], [], []
            for a in range(3):
                ca = dr.clip(I(dr.floor(at[a] + t_in * per_t[a])), 0, dims[a] - 1)
                c.append(ca)
                step.append(dr.select(per_t[a] > 0, 1, dr.select(per_t[a] < 0, -1, 0)))
                t_next.append(self._face(ca, at[a], per_t[a], inv_p[a]))
            cx, cy, cz = c
            tnx, tny, tnz = t_next
            t_enter = F(t_in)
            first = dr.full(mi.Bool, True, n)
            moved = dr.full(I, -1, n)
            while active:
                t_exit = dr.minimum(dr.minimum(tnx, tny), dr.minimum(tnz, t_out))
                # The cells this step adds: per axis a range of layers, clamped to the grid; of them, the
                # layers the segment comes within reach of over the part of it near all three ranges.
                cc = (cx, cy, cz)
                lo_, hi_ = [], []
                t0, t1 = t_in, dr.minimum(t_out, best_t)
                for a in range(3):
                    slab = ~first & (moved == a)
                    lo_.append(dr.maximum(dr.select(slab, cc[a] + step[a], cc[a] - 1), 0))
                    hi_.append(dr.minimum(dr.select(slab, cc[a] + step[a], cc[a] + 1), dims[a] - 1))
                    t0, t1 = self._near(at[a], per_t[a], inv_p[a], lo_[a], hi_[a], reach, t0, t1)
                for a in range(3):
                    u0, u1 = at[a] + t0 * per_t[a], at[a] + t1 * per_t[a]
                    lo_[a] = dr.maximum(lo_[a], I(dr.floor(dr.minimum(u0, u1) - reach)))
                    hi_[a] = dr.minimum(hi_[a], I(dr.floor(dr.maximum(u0, u1) + reach)))
                x0, y0, z0 = lo_
                x1, y1, z1 = hi_
                near = (t0 <= t1) & (x0 <= x1) & (y0 <= y1) & (z0 <= z1)
                # The exact tests run from the ray's point at the step's entry (single precision keeps
                # the offsets to the grains small there).
                base = [o[a] + t_enter * d[a] for a in range(3)]
                # One loop over the step's rows of cells x0..x1 at (y, z) (each a run of grains) and their
                # grains: an iteration reads the next row where the current one is done, then tests a
                # grain where one is left, so that lanes with rows of different lengths keep busy.
                y, z = I(y0), dr.select(near, z0, z1 + 1)
                yr, zr = I(y), I(z)
                g, g1 = U(0), U(0)
                while (g < g1) | (z <= z1):
                    fetch = g >= g1
                    row = soff + U((z * dims[1] + y) * dims[0])
                    live = ~fetch
                    if dr.hint(lattice, mode="scalar"):
                        # One pair of gathers: the row's first and end grain where a lane reads a row, else its
                        # grain's two words (``_cells``).
                        ia = dr.select(fetch, s_off + row + U(x0), 2 * g)
                        ib = dr.select(fetch, s_off + row + U(x1 + 1), 2 * g + 1)
                        wa, wb = dr.gather(U, self._cells, ia), dr.gather(U, self._cells, ib)
                        g = dr.select(fetch, wa, g)
                        g1 = dr.select(fetch, wb, g1)
                    else:
                        g = dr.select(fetch, self.start_of(row + U(x0), fetch), g)
                        g1 = dr.select(fetch, self.start_of(row + U(x1 + 1), fetch), g1)
                        live = g < g1
                    yr = dr.select(fetch, y, yr)  # the row being read
                    zr = dr.select(fetch, z, zr)
                    wrap = fetch & (y >= y1)
                    y = dr.select(fetch, dr.select(wrap, y0, y + 1), y)
                    z = dr.select(wrap, z + 1, z)
                    if dr.hint(lattice, mode="scalar"):  # a lane that read a row tests its grains next
                        centre, tid = self.decode(wa, wb, frame, x0, yr, zr)
                        radius = None
                    else:  # a lane that read a row tests its first grain at once
                        centre, radius, tid = self.grain(g, frame, x0, yr, zr, live)
                    v = [centre[a] - base[a] for a in range(3)]
                    tt = v[0] * d[0] + v[1] * d[1] + v[2] * d[2]
                    q = [v[a] - tt * d[a] for a in range(3)]
                    t_i = t_enter + tt
                    d2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2]
                    # Within the class's reach (no read of the grain's own R): a candidate. The rest of
                    # the test, and what a hit costs, in a branch that a SIMD packet without a candidate
                    # skips (most: the rows hold grains up to a cell away from the ray).
                    cand = live & (d2 < reach_w2) & (t_i >= 0) & (t_i < best_t)
                    if dr.hint(cand, mode="symbolic"):  # symbolic whatever the variant's flags say
                        r_i = self.radius_of(tid, cand) if radius is None else radius
                        hit = cand & (d2 < r_i * r_i)
                        if excluding:  # the centre's offset from the ray's origin: v + t_enter d
                            w = [v[a] + t_enter * d[a] for a in range(3)]
                            r_x = r_i * (1 + EXCLUDE_MARGIN)
                            o2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
                            if dr.hint(tagged, mode="scalar"):  # the origin tag: its grain (and 1 in 2^b - 1 others)
                                hit &= ~exclude_origin | (o2 >= r_x * r_x) | ~tags_agree(o_hash, grain_hash(g),
                                                                                         r_i, o_m, thresholds)
                            else:
                                hit &= ~exclude_origin | (o2 >= r_x * r_x)
                        tau_i = F(self.tau_of(tid, hit))
                        if flight:
                            w0, w1 = _mix(key0 + g * _GOLDEN), _mix(key1 ^ (g * _GOLDEN2))
                            uu = (mi.Float64(w0) + mi.Float64(w1) * 2.0**-32) * 2.0**-32
                            interacts = hit & (uu < mi.Float64(one_minus_exp(mi.Float(tau_i))))
                            best_t = dr.select(interacts, t_i, best_t)
                            best_g = dr.select(interacts, g, best_g)
                            if dr.hint(ball, mode="scalar"):
                                bx = dr.select(interacts, centre[0], bx)
                                by = dr.select(interacts, centre[1], by)
                                bz = dr.select(interacts, centre[2], bz)
                                br = dr.select(interacts, r_i, br)
                        else:
                            tau += dr.select(hit, tau_i, 0)
                    g = dr.select(live, g + 1, g)
                # The next step: along the axis whose face comes first; the walk ends at the box's exit,
                # or (a free flight) once it has interacted before this step's exit.
                ax = dr.select(tny < tnx, 1, 0)
                tmin = dr.minimum(tnx, tny)
                ax = dr.select(tnz < tmin, 2, ax)
                tmin = dr.minimum(tmin, tnz)
                go = (tmin < t_out) & (best_t > t_exit)
                cx = dr.select(go & (ax == 0), cx + step[0], cx)
                cy = dr.select(go & (ax == 1), cy + step[1], cy)
                cz = dr.select(go & (ax == 2), cz + step[2], cz)
                tnx = dr.select(go & (ax == 0), self._face(cx, at[0], per_t[0], inv_p[0]), tnx)
                tny = dr.select(go & (ax == 1), self._face(cy, at[1], per_t[1], inv_p[1]), tny)
                tnz = dr.select(go & (ax == 2), self._face(cz, at[2], per_t[2], inv_p[2]), tnz)
                inside = (cx >= 0) & (cx < dims[0]) & (cy >= 0) & (cy < dims[1]) & (cz >= 0) & (cz < dims[2])
                active = go & inside
                t_enter = t_exit
                first = dr.full(mi.Bool, False, n)
                moved = ax
            k += 1
        return (tau, best_t, best_g) + ((([bx, by, bz], br),) if ball else ())

    def _face(self, c, at, per_t, inv_p):
        """``face`` in the walk's precision."""
        return face(c, at, per_t, inv_p, self.F)

    def _near(self, at, per_t, inv_p, m0, m1, reach, t0, t1):
        """``near`` in the walk's precision."""
        return near(at, per_t, inv_p, m0, m1, reach, t0, t1, self.F)
