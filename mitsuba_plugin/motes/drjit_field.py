"""The continuous field of a discrete medium's continuous size classes in Dr.Jit-typed code (issue 46): the
``kernel = "drjit"`` counterpart of ``rust/motes-core/src/render/continuous/``, for a wavefront of rays in the
current Mitsuba variant's JIT types.

The physics is the core's (``continuous/mod.rs``, "Why this is the same medium"); this module reads a built
field as flat arrays (``DiscreteMedium.flat_field``, ``continuous/export.rs``) and walks it:

* σ_t is constant per cell (the extinction of the class members whose centre lies in it over its volume), so
  the optical depth of a segment is tau(t) = sum over the cells crossed of σ_c Δt_c (a 3D-DDA, Amanatides &
  Woo, as ``ContinuousField::optical_depth``).
* a free flight is exact: one unit exponential target -ln(u) per ray, σ_c Δt_c accumulated cell by cell, and
  the flight stops in the cell where the target is reached, at t = t_enter + (target - tau(t_enter)) / σ_c
  (``ContinuousField::free_flight``): P(t_hit > t) = exp(-tau(t)). The native kernel samples the same
  distribution by delta tracking (different random numbers).
* an interaction in a cell scatters from one of its members picked ∝ its extinction (``ContinuousField::pick``):
  its bin's albedo and phase function, so the expected phase function is the cell's mixture weighted by the
  shares s_i (Eq. 24's Q(θ) of the cell). ``cell_walk`` visits a cell's entries (one per bin, with its share)
  for the phase function's steps (``plugins/drjit_medium.py``).

The walk runs in ``self.F`` (``mi.Float``, or ``mi.Float64`` with ``double=True`` for tests): cell faces and
optical depths summed in single precision lose a few 1e-7 relative per cell crossed.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .drjit_walk import face, near

#: The constant the field's TEA hash mixes with a flight's seed (the grains' walk hashes the same seed with
#: another one, ``drjit_walk._walk``): the two processes draw independent numbers.
FIELD_KEY = 0xF1E1D
#: TEA rounds of a flight's exponential.
TEA_ROUNDS = 8
#: Margin (in cells) within which a point just outside the field's box (rounding of p = o + t d at a face)
#: still reads the nearest cell (``cell_at``).
CELL_MARGIN = 1e-3


class DrJitField:
    """A continuous field uploaded once as the current variant's JIT arrays: ``sample_free_flight``,
    ``optical_depth``, ``cell_at`` and ``cell_walk`` (module docs). ``field``: the dict of
    ``DiscreteMedium.flat_field`` (or a ``motes._motes.DiscreteMedium`` / ``motes.DiscreteMedium`` holding one)."""

    def __init__(self, field, *, double: bool = False):
        if not mi.variant() or not mi.variant().startswith(("llvm_", "cuda_")):
            raise RuntimeError(f"motes.drjit_field needs a JIT variant (llvm_* or cuda_*), not {mi.variant()!r}")
        if not isinstance(field, dict):
            core = getattr(field, "core", field)
            field = core.flat_field()
            if field is None:
                raise ValueError("the medium has no continuous field (continuous_count = inf, or every size class "
                                 "discrete)")
        self.double = bool(double)
        self.F = mi.Float64 if self.double else mi.Float
        dims = np.asarray(field["dims"], dtype=np.int64)
        sigma = np.ascontiguousarray(field["sigma"], dtype=np.float32)
        start = np.ascontiguousarray(field["start"], dtype=np.uint32)
        if dims.size != 3 or sigma.size != int(np.prod(dims)) or start.size != sigma.size + 1:
            raise ValueError(f"flat_field: {sigma.size} sigma and {start.size} starts for dims {dims.tolist()}")
        if not np.all(np.isfinite(sigma)) or sigma.min(initial=0.0) < 0:
            raise ValueError("flat_field: sigma must be finite and >= 0")
        self.cells = int(sigma.size)
        self.entries = int(start[-1])
        self.lo = np.asarray(field["lo"], dtype=np.float64)
        self.cell = np.asarray(field["cell"], dtype=np.float64)
        self.dims = [int(x) for x in dims]
        self._lo = [dr.opaque(self.F, float(x)) for x in self.lo]
        self._inv_cell = [dr.opaque(self.F, 1.0 / float(x)) for x in self.cell]
        self._dims = [dr.opaque(mi.Int32, x) for x in self.dims]
        self._sigma = mi.Float(sigma)
        self._start = mi.UInt32(start)
        self._bin = mi.UInt32(np.ascontiguousarray(field["bin"], dtype=np.uint32))
        self._share = mi.Float(np.ascontiguousarray(field["share"], dtype=np.float32))

    @property
    def nbytes(self) -> int:
        """Bytes of the uploaded arrays: σ_t and the entry starts per cell, bin and share per entry."""
        return 4 * (2 * self.cells + 1) + 8 * self.entries

    # ------------------------------------------------------------------------------------------ queries

    def optical_depth(self, origin, direction, tmax):
        """Optical depth (``self.F``) of the segments [0, tmax) of the rays ``origin + t direction`` (t in units
        of the normalised direction; tmax may be inf): sum of σ_c Δt_c over the cells crossed."""
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            _, tau, _ = self._walk(origin, direction, tmax, None)
        return tau

    def sample_free_flight(self, origin, direction, tmax, seed):
        """Exact free flights on [0, tmax): ``(t, valid)``, the distance where the optical depth reaches a unit
        exponential target -ln(u) (``self.F``; inf where it is not reached before tmax) and whether it is. ``seed``:
        per ray a ``mi.UInt32`` (hashed with ``FIELD_KEY`` into u = (h + 1/2) / 2^32, as the core's ``exponential``)
        or a ``mi.Float`` uniform in [0, 1) used as u directly (tests: the target -ln(1 - u))."""
        if isinstance(seed, mi.UInt32):
            h, _ = mi.sample_tea_32(seed, mi.UInt32(FIELD_KEY), TEA_ROUNDS)
            target = -dr.log((mi.Float64(h) + 0.5) * 2.0**-32)
        else:
            target = -dr.log(1 - mi.Float64(seed))
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            t, _, valid = self._walk(origin, direction, tmax, self.F(target))
        return dr.select(valid, t, dr.inf), valid

    def cell_at(self, p, active=True):
        """The cell holding point ``p`` (``mi.UInt32``) and whether it is inside the field (within
        ``CELL_MARGIN`` cells of its box: a flight's point rounded across a face reads the nearest cell) with
        σ_t > 0: ``(cell, sigma, inside)``."""
        F, I = self.F, mi.Int32
        c, inside = [], mi.Bool(active)
        for a in range(3):
            x = (F(p[a]) - self._lo[a]) * self._inv_cell[a]
            inside &= (x >= -CELL_MARGIN) & (x < self._dims[a] + CELL_MARGIN)
            c.append(dr.clip(I(dr.floor(x)), 0, self._dims[a] - 1))
        cell = mi.UInt32((c[2] * self._dims[1] + c[1]) * self._dims[0] + c[0])
        sigma = dr.gather(mi.Float, self._sigma, cell, inside)
        return cell, sigma, inside & (sigma > 0)

    def mixture_at(self, p, active=True):
        """The entries of the cell holding ``p``: ``(first, end, sigma, valid)``, entries ``first..end`` of
        ``entry``'s arrays (none where ``valid`` is False: outside the field or σ_t = 0)."""
        cell, sigma, valid = self.cell_at(p, active)
        first = dr.gather(mi.UInt32, self._start, cell, valid)
        end = dr.select(valid, dr.gather(mi.UInt32, self._start, cell + 1, valid), first)
        return first, end, sigma, valid

    def entry(self, j, active=True):
        """Entry ``j``: (its bin, its share of its cell's extinction)."""
        return dr.gather(mi.UInt32, self._bin, j, active), dr.gather(mi.Float, self._share, j, active)

    @dr.syntax
    def cell_walk(self, p, visit, state, active=True):
        """``state = visit(share, bin, member, state)`` at each entry of the cell holding ``p`` (``member`` True
        there), where ``active`` and the cell has σ_t > 0; ``state`` (a list of JIT values) returned."""
        first, end, _, valid = self.mixture_at(p, active)
        j = mi.UInt32(first)
        state = list(state)
        while valid & (j < end):
            live = j < end
            b, s = self.entry(j, live)
            state = list(visit(s, b, live, state))
            j += 1
        return state

    # ------------------------------------------------------------------------------------------ the walk

    @dr.syntax
    def _walk(self, origin, direction, tmax, target):
        """The DDA through the cells (module docs): (t where the optical depth reaches ``target``, the optical
        depth walked up to it or to tmax, whether it was reached); ``target`` None: the optical depth alone."""
        F, I = self.F, mi.Int32
        o = [F(origin[a]) for a in range(3)]
        d = [F(direction[a]) for a in range(3)]
        norm = dr.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        d = [x / norm for x in d]
        n = max(dr.width(o[0]), dr.width(d[0]), dr.width(F(tmax)), 1 if target is None else dr.width(target))
        goal = dr.full(F, dr.inf, n) if target is None else F(target) + dr.zeros(F, n)
        # The ray in cell coordinates x(t) = at + t per_t; the segment inside the box by a slab test.
        at = [(o[a] - self._lo[a]) * self._inv_cell[a] + dr.zeros(F, n) for a in range(3)]
        per_t = [d[a] * self._inv_cell[a] for a in range(3)]
        inv_p = [1 / p for p in per_t]
        t_in, t_out = dr.zeros(F, n), F(tmax) + dr.zeros(F, n)
        for a in range(3):
            t_in, t_out = near(at[a], per_t[a], inv_p[a], 0, self._dims[a] - 1, 0.0, t_in, t_out, F)
        active = t_in < t_out
        c, step = [], []
        for a in range(3):
            c.append(dr.clip(I(dr.floor(at[a] + t_in * per_t[a])), 0, self._dims[a] - 1))
            step.append(dr.select(per_t[a] > 0, 1, dr.select(per_t[a] < 0, -1, 0)))
        cx, cy, cz = c
        tnx, tny, tnz = (face(c[a], at[a], per_t[a], inv_p[a], F) for a in range(3))
        t_enter = F(t_in)
        tau = dr.zeros(F, n)
        t_hit = dr.full(F, dr.inf, n)
        hit = dr.zeros(mi.Bool, n)
        while active:
            t_exit = dr.minimum(dr.minimum(tnx, tny), dr.minimum(tnz, t_out))
            cell = mi.UInt32((cz * self._dims[1] + cy) * self._dims[0] + cx)
            s = F(dr.gather(mi.Float, self._sigma, cell, active))
            x = s * dr.maximum(t_exit - t_enter, 0)
            # The target reached in this cell: t = t_enter + (target - tau) / sigma (ContinuousField::free_flight).
            reach = (s > 0) & (tau + x > goal)
            t_hit = dr.select(reach, dr.minimum(t_enter + (goal - tau) / dr.select(s > 0, s, 1), t_exit), t_hit)
            hit |= reach
            tau = dr.select(reach, goal, tau + x)
            # The next cell: along the axis whose face comes first, until the box's (or the segment's) end.
            ax = dr.select(tny < tnx, 1, 0)
            tmin = dr.minimum(tnx, tny)
            ax = dr.select(tnz < tmin, 2, ax)
            tmin = dr.minimum(tmin, tnz)
            go = ~reach & (tmin < t_out)
            cx = dr.select(go & (ax == 0), cx + step[0], cx)
            cy = dr.select(go & (ax == 1), cy + step[1], cy)
            cz = dr.select(go & (ax == 2), cz + step[2], cz)
            tnx = dr.select(go & (ax == 0), face(cx, at[0], per_t[0], inv_p[0], F), tnx)
            tny = dr.select(go & (ax == 1), face(cy, at[1], per_t[1], inv_p[1], F), tny)
            tnz = dr.select(go & (ax == 2), face(cz, at[2], per_t[2], inv_p[2], F), tnz)
            inside = ((cx >= 0) & (cx < self._dims[0]) & (cy >= 0) & (cy < self._dims[1]) & (cz >= 0)
                      & (cz < self._dims[2]))
            active = go & inside
            t_enter = t_exit
        return t_hit, tau, hit
