"""The walk of the particle grid in Dr.Jit-typed code (issue 46, first slice): optical depth along a ray and
exact free flights to the first grain interaction, for a wavefront of rays, in the current Mitsuba variant's
JIT types (``llvm_ad_*``, later ``cuda_ad_*``: a CUDA kernel cannot call the Rust core).

Not wired into the medium plugin yet. The physics is the Rust core's (``rust/motes-core/src/space/grid/``);
this module only reads a built grid's grains as flat arrays (``ParticleGrid.flat_arrays`` or
``DiscreteMedium.flat_arrays``, ``rust/motes-core/src/space/grid/flat.rs``) and walks them:

* grain i contributes to a ray when the ray passes within R_i = r_c + r_i of its centre and the projection
  t_i of the centre on the ray lies in the segment [0, t_max); it adds its disk's optical depth tau_i (the
  paper's Eq. 18 normalised per disk, ``rust/motes-core/src/space/grid/mod.rs``). The optical depth of a
  segment is the sum; its transmittance exp(-tau).
* a free flight interacts at grain i with probability 1 - exp(-tau_i), independently of the others, and
  stops at the first grain (smallest t_i) that interacts: P(grain j) = prod_{t_i < t_j} exp(-tau_i) (1 -
  exp(-tau_j)), the distribution the Rust walk samples by inversion of one uniform along the ordered grains
  (``ParticleGrid::free_flight``). Here each grain draws its own uniform from a hash (TEA, 8 rounds) of the
  ray's seed and the grain's position in the flat arrays, so that the walk need not visit the grains in t
  order: the same distribution, not the same sample for the same ``u``.

The walk (per size class of the grid, each with its own cells, at least as wide as the class's largest
inclusion radius): a 3D-DDA over the cells the ray crosses (Amanatides & Woo), and per step the cells of the
3x3x3 block around the step's cell that no earlier step tested: the whole block at the first step, then the
3x3 slab each move adds on the far side (a DDA step moves along one axis, and monotonically). Every grain
whose ball reaches the ray is in such a block, and in exactly one slab: a grain that straddles cells is
stored once, in its centre's cell, and tested once. Of a step's cells, only the layers (per axis) the
segment comes within the class's reach of, over the part of it that is near all three ranges, are read
(the Rust walk's ``Near``), a row (a run of cells along x, contiguous in the arrays) at a time. Once a
step is done every grain with t_i before its
exit has been tested, so a free flight stops there once it has interacted before that exit, and the next
class walks only up to that interaction (the classes are independent).

Precision: ``double=False`` walks in the variant's ``Float`` (single precision: the exact test runs from an
origin moved to each step's entry, so that its error is a few 1e-7 of the cell and of the coordinates'
scale; grains within that of their disk's edge or of the segment's ends may fall either way),
``double=True`` in ``Float64`` (the Rust core's precision, for tests). Optical depths are summed in the
walk's precision (single: a relative rounding of ~1e-7 per grain met; a ``Float64`` sum made the single
walk 25 % slower on ``bench_drjit_walk.py``'s 1e5 grains). A free flight's interaction probabilities
1 - exp(-tau_i) and its uniforms are in ``Float64`` either way (64 random bits: a grain of tau_i ~ 1e-9 keeps
its probability).

``DrJitGrid(grid)``: ``grid`` is a ``motes.ParticleGrid`` or ``motes.DiscreteMedium`` (or their
``motes._motes`` cores), or the dict their ``flat_arrays`` return. The kernels run with symbolic loops
whatever the flag says (the plugins' evaluated mode would run each loop iteration as a kernel).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from . import _motes

#: TEA rounds of a grain's uniform in a free flight (``mi.sample_tea_32(seed, grain position)``). Mitsuba's
#: samplers use 4: here 4 fail ``tests/test_drjit_walk.py``'s chi-square of 1.2e5 flights (p < 1e-4, with
#: random 32-bit seeds too: the grains along a ray have nearby positions); 6 and 8 pass (p 0.05-0.9 over 12
#: sets of seeds).
TEA_ROUNDS = 8
#: Margin of the class box the DDA clips to, and of the rows' reach, in cells: rounding of the cell
#: coordinates must not drop a grain the exact test accepts (a wider margin only tests a few more).
CELL_MARGIN = 1e-3
#: Relative margin of the rows' reach (see ``CELL_MARGIN``).
REACH_MARGIN = 1e-4
#: Relative growth of a grain's ball in ``exclude_origin``: a ray leaving a site at the float32 projection of
#: a grain's centre must not meet that grain again where rounding puts the site a hair outside its ball.
EXCLUDE_MARGIN = 1e-4
_NONE = 0xFFFFFFFF


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


def _one_minus_exp(x):
    """1 - exp(-x) (Float64) without its cancellation for small x: a series below 0.05 (error < 1e-12
    relative), else exp."""
    s = x * (1 - x * (1 / 2 - x * (1 / 6 - x * (1 / 24 - x * (1 / 120 - x * (1 / 720))))))
    return dr.select(x < 0.05, s, 1 - dr.exp(-x))


class DrJitGrid:
    """A grid's grains uploaded once as the current variant's JIT arrays, walked by ``optical_depth``,
    ``transmittance`` and ``sample_free_flight`` (module docs)."""

    def __init__(self, grid, *, channel: int = 0, double: bool = False):
        if not mi.variant() or not mi.variant().startswith(("llvm_", "cuda_")):
            raise RuntimeError(f"motes.drjit_walk needs a JIT variant (llvm_* or cuda_*), not {mi.variant()!r}")
        a = _arrays_of(grid, channel)
        self.double = bool(double)
        self.F = mi.Float64 if self.double else mi.Float
        spheres = np.ascontiguousarray(a["spheres"], dtype=np.float32)
        self.count = int(spheres.shape[0])
        self.classes = int(len(a["class_cell"]))
        self.bytes_per_grain = 24  # centre and R (16, read per grain tested), tau (4), index (4)
        self.cells = int(len(a["start"]))
        # The grains (module docs of rust/motes-core/src/space/grid/flat.rs).
        self._spheres = mi.Float(spheres.ravel())
        self._tau = mi.Float(np.ascontiguousarray(a["tau"], dtype=np.float32))
        self._index = mi.UInt32(np.ascontiguousarray(a["index"], dtype=np.uint32))
        self._start = mi.UInt32(np.ascontiguousarray(a["start"], dtype=np.uint32))
        self.bin = np.asarray(a["bin"]) if "bin" in a else None
        # Per class: corner, 1 / cell, cells per axis, reach in cells (with margins), first cell start.
        cell = np.asarray(a["class_cell"], dtype=np.float64)
        self._lo = self.F(np.ascontiguousarray(np.asarray(a["class_lo"], dtype=np.float64).ravel()))
        self._inv_cell = self.F(1.0 / cell)
        self._dims = mi.Int32(np.ascontiguousarray(np.asarray(a["class_dims"]).ravel().astype(np.int32)))
        reach_cells = np.asarray(a["class_reach"], dtype=np.float64) / cell
        self._reach = self.F(reach_cells * (1 + REACH_MARGIN) + CELL_MARGIN)
        self._class_start = mi.UInt32(np.asarray(a["class_start"]).astype(np.uint32))
        self._n_classes = dr.opaque(mi.UInt32, self.classes)

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

    def sample_free_flight(self, origin, direction, tmax, u, *, exclude_origin=False):
        """Exact free flights on [0, tmax): ``(t, index, valid)``: the distance to the first grain that
        interacts (``self.F``; inf where none), the index the grid reports for it (``mi.UInt32``; 2^32 - 1
        where none) and whether there is one. ``u``: per ray a uniform ``mi.Float`` in [0, 1) (its bits seed
        the grains' draws) or a ``mi.UInt32`` seed (module docs). ``exclude_origin`` (a bool, or per ray a
        ``mi.Bool``): grains whose ball (radius R_i, grown by ``EXCLUDE_MARGIN``) holds the ray's origin are
        skipped (the medium plugin's stateless "parent" exclusion: a ray leaving a site skips its grains)."""
        if isinstance(u, mi.UInt32):
            seed = u
        else:
            seed = dr.reinterpret_array(mi.UInt32, mi.Float(u))
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            _, t, g = self._walk(origin, direction, tmax, seed, exclude_origin)
        valid = g != _NONE
        index = dr.gather(mi.UInt32, self._index, g, valid)
        return dr.select(valid, t, dr.inf), dr.select(valid, index, _NONE), valid

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
    def _walk(self, origin, direction, tmax, seed, exclude_origin=False):
        """The walk of every class (module docs): (optical depth, first interaction's t, its grain's position
        or 2^32 - 1); a free flight where ``seed`` is given, else the optical depth alone."""
        F, I, U = self.F, mi.Int32, mi.UInt32
        o, d, best_t, n = self._rays(origin, direction, tmax)
        flight = seed is not None
        excluding = exclude_origin is not False
        if excluding:
            exclude_origin = mi.Bool(exclude_origin) | dr.zeros(mi.Bool, n)
        if flight:
            seed = U(seed) + dr.zeros(U, n)
        tau = dr.zeros(F, n)
        best_g = dr.full(U, _NONE, n)
        k = dr.zeros(U, n)
        while k < self._n_classes:
            # The class's frame, the ray in its cell coordinates x(t) = at + t per_t.
            inv_cell = dr.gather(F, self._inv_cell, k)
            reach = dr.gather(F, self._reach, k)
            soff = dr.gather(U, self._class_start, k)
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
                ny = dr.maximum(y1 - y0 + 1, 1)  # (a divisor in every lane: masked lanes divide too)
                near = (t0 <= t1) & (x0 <= x1) & (y0 <= y1) & (z0 <= z1)
                rows = dr.select(near, ny * (z1 - z0 + 1), 0)
                # The exact tests run from the ray's point at the step's entry (single precision keeps
                # the offsets to the grains small there).
                base = [o[a] + t_enter * d[a] for a in range(3)]
                r = dr.zeros(I, n)
                while r < rows:
                    # A row of cells x0..x1 at (y, z): a run of grains.
                    y = y0 + r % ny
                    z = z0 + r // ny
                    row = soff + U((z * dims[1] + y) * dims[0])
                    g = dr.gather(U, self._start, row + U(x0))
                    g1 = dr.gather(U, self._start, row + U(x1 + 1))
                    while g < g1:
                        s = dr.gather(mi.Vector4f, self._spheres, g)
                        v = [F(s[a]) - base[a] for a in range(3)]
                        tt = v[0] * d[0] + v[1] * d[1] + v[2] * d[2]
                        q = [v[a] - tt * d[a] for a in range(3)]
                        radius = F(s[3])
                        t_i = t_enter + tt
                        hit = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] < radius * radius) & (t_i >= 0) & (t_i < best_t)
                        if excluding:  # the centre's offset from the ray's origin: v + t_enter d
                            w = [v[a] + t_enter * d[a] for a in range(3)]
                            r_x = radius * (1 + EXCLUDE_MARGIN)
                            hit &= ~exclude_origin | (w[0] * w[0] + w[1] * w[1] + w[2] * w[2] >= r_x * r_x)
                        tau_i = F(dr.gather(mi.Float, self._tau, g, hit))
                        if flight:
                            w0, w1 = mi.sample_tea_32(seed, g, TEA_ROUNDS)
                            uu = (mi.Float64(w0) + mi.Float64(w1) * 2.0**-32) * 2.0**-32
                            interacts = hit & (uu < _one_minus_exp(mi.Float64(tau_i)))
                            best_t = dr.select(interacts, t_i, best_t)
                            best_g = dr.select(interacts, g, best_g)
                        else:
                            tau += dr.select(hit, tau_i, 0)
                        g += 1
                    r += 1
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
        return tau, best_t, best_g

    def _face(self, c, at, per_t, inv_p):
        """t of the face the ray leaves cell layer ``c`` by (inf along an axis it does not move on)."""
        F = self.F
        return dr.select(per_t > 0, (F(c + 1) - at) * inv_p, dr.select(per_t < 0, (F(c) - at) * inv_p, dr.inf))

    def _near(self, at, per_t, inv_p, m0, m1, reach, t0, t1):
        """The part of [t0, t1] where the ray's coordinate ``at + t per_t`` lies within ``reach`` (cells) of
        layers ``m0..m1``: (ta, tb), empty when ta > tb."""
        F = self.F
        u0 = (F(m0) - reach - at) * inv_p
        u1 = (F(m1 + 1) + reach - at) * inv_p
        flat = per_t == 0
        inside = (at >= F(m0) - reach) & (at <= F(m1 + 1) + reach)
        lo = dr.select(flat, dr.select(inside, -dr.inf, dr.inf), dr.minimum(u0, u1))
        hi = dr.select(flat, dr.select(inside, dr.inf, -dr.inf), dr.maximum(u0, u1))
        return dr.maximum(t0, lo), dr.minimum(t1, hi)
