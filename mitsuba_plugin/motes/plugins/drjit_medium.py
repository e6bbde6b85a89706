"""``kernel = "drjit"``: the ``discrete`` medium and its ``particle`` phase function as Dr.Jit-typed code,
traced into Mitsuba's symbolic kernels (issue 46, second slice). No numpy and no Rust call at render time:
the grains are uploaded once as JIT arrays (``motes.drjit_walk``) and walked in the kernel, so the same code
can run where a kernel cannot call the Rust core (``cuda_ad_*``: the default and only kernel there).

===================  =======  ================================================================================
Parameter            Type     Meaning (of the ``discrete`` medium; the other parameters keep theirs)
===================  =======  ================================================================================
``kernel``           string   ``native`` (the C++/Rust plugin where it is built: ``scalar_*``, ``llvm_ad_*``) or
                              ``drjit`` (this file; every ``llvm_ad_*`` and ``cuda_ad_*`` variant, polarised ones
                              included) (``native``; ``drjit``, the only one, in ``cuda_ad_*``)
===================  =======  ================================================================================

Notes
-----
* **Level of detail.** Every grain of the discrete size classes is walked on every ray; the size classes no
  pixel resolves (``continuous_count``, 16 by default as in the native kernel) are their continuous field (next
  note), stored or procedural. The scalar variants (``kernel`` named) and a procedural cloud of a grid density
  whose grains are not all continuous are errors. ``grain_depth`` and ``surface_footprint`` change nothing: no
  ray switches to the grains' continuous equivalent (as native with ``grain_depth`` at its maximum and
  ``surface_footprint = false``); where every class is continuous that is the native default's model. A user's
  ``<phase>`` child (``isotropic``, ``hg``, ``tabphase``) and ``phase_model = "hg"`` work: they are per-bin
  tables like the grains' own.
* **Continuous size classes** (a finite ``continuous_count``; ``rust/motes-core/src/render/continuous/``): the
  field of the classes no pixel resolves is uploaded once (``DiscreteMedium.flat_field``: sigma_t per cell, per
  cell its bins with their shares s_i of its extinction) and walked by ``motes.drjit_field.DrJitField``: an
  exact free flight through the piecewise-constant sigma_t (one exponential per ray, accumulated along a 3D-DDA),
  then the grains' flight up to its distance; the two processes are independent, so the nearer interaction
  wins (as the native kernel's ``discrete/flight.rs``). At a point where the site search finds no grain and
  whose cell has sigma_t > 0, the phase function is the cell's: the site's formulas below with tau_j replaced
  by s_i (value_c = sum_i s_i a_ic f_ic / sum_i s_i; sampling picks a bin by s_i a_ic), which is what the native
  kernel's pick of one member by its extinction gives in expectation. A field event keeps its point (no tag
  search): the rays leaving it skip a grain whose ball holds it only where their tags agree by chance (1 in
  64; below, "Parent exclusion").
* **Procedural clouds** (``storage = procedural``): nothing is stored; ``motes.drjit_procedural`` regenerates the
  grains of the tiles a ray or a site needs from the core's counter-seeded streams, the core's grains bit for bit
  (``DrJitProcedural.sample_free_flight`` and ``site_walk``). Every ray regenerates its tiles (the native kernel
  caches bricks), those it can meet only, and tests only the grains within reach of it: exact (every grain walked)
  2.5-2.7x (limit) and 3.0-3.4x (lamp) the native kernel's CPU time (14-22x before those skips); at the defaults,
  whose field holds the classes no pixel resolves, as fast as native (``bench_drjit_kernel.py -D
  storage=procedural``). Its continuous classes are a field as a stored set's (previous note): the core's
  (``ProceduralParts::field``, the density's expected extinction of those classes per cell, 64 cells along the box's
  longest side), at rest where a drift moves the grains, as the native kernel's; the field's flight comes first, the
  regenerated grains are walked up to it (``intersect_aabb``), and a field event's phase function is its cell's
  mixture (``_site_sums``, after the procedural site walk finds no grain). Where every class is continuous the field
  alone is walked (``DrJitProcedural`` is not built). Measured (2026-11-29, BENCHMARKS.md): against native on the
  same settings, ``bench_drjit_kernel.py --scenes mixed`` (small grains continuous, large ones discrete) z -1.62,
  RMS/noise 0.92 over 16 seeds, and with a drift (``-D turbulence=0.05 -D time=1``) z -0.55, 1.00 over 24; a
  procedural white furnace of 17 558 continuous grains in 20 000 (``bench_drjit_furnace.py --storage procedural
  --continuous-count 1``) 1.00062 +- 0.00089.
* **Free flights** (``intersect_aabb``): ``DrJitGrid.sample_free_flight`` (a procedural cloud:
  ``DrJitProcedural.sample_free_flight``) from the ray's origin up to its ``maxt``, or up to the continuous field's
  own flight where it has one (the nearer of the two wins), each grain interacting with probability 1 - exp(-tau_i),
  the nearest that does returned as ``mint`` (``maxt`` = inf), ``hit = False`` where none. Its random numbers hash
  the ray (origin, direction, ``maxt``) and the medium's ``seed``: a render is a function of scene, seed and spp.
  ``get_majorant`` returns ``MAJORANT`` and ``get_scattering_coefficients`` sigma_s = sigma_t = ``MAJORANT``,
  sigma_n = 0, as the native kernel does (``discrete``'s notes, "How it maps onto Mitsuba's delta tracking"): no
  null collisions; the site's albedo rides on the phase function's value and weight.
* **Parent exclusion without state: the origin tag.** A ray leaving a site must not meet the grain it scatters from
  (its internal paths are in its phase function); the native kernel remembers events and skips the site's grains. A
  Dr.Jit kernel cannot remember events per lane (a ``dr.gather`` from a buffer the same symbolic kernel
  ``dr.scatter``\\ s into reads the contents from before the kernel), and Mitsuba's shadow rays (``spawn_ray_to``,
  their direction the emitter's) carry nothing of ours: the rule must read the ray's *origin* alone. Mitsuba puts a
  medium event at ``mei.p = ray(mint + (-log(1 - u)) / majorant) = fma(d, mint, o)``, which with ``MAJORANT`` = 1e20
  is fma(d, mint, o) exactly (mint > ~3e-12), and the rays leaving it, scattered and shadow, start at p exactly (n =
  0: ``offset_p`` adds 0). So ``intersect_aabb`` (``_tag_search``) returns, among the floats t* = t + k delta near the
  flight's t (k = 0, 1, -1, 2, ...; delta ``_tag_step``: an ulp of p's largest coordinate over the direction's largest
  component, or an ulp of t where that is coarser), the first whose point lies inside its grain's ball (R_i, as the
  walk read it: ``want_ball``) and whose ``drjit_walk.origin_tag`` (6 bits, ``TAG_BITS``, of the coordinates' float32
  bits) equals its grain's ``grain_tag`` (a hash of its position in the flat arrays; procedural: of its key; 0 to 62:
  tag 63, ``FIELD_TAG``, is no grain's; fewer bits in balls a few ulps wide, below, ``tags_agree``). A field event
  (continuous classes) moves, with no ball to stay in, to a point of ``FIELD_TAG``. Every ray (camera, surface,
  scattered, shadow) then skips exactly the grains whose ball (R_i grown by ``EXCLUDE_MARGIN``, which absorbs the
  walk's rounding of the distance the search tested) holds its origin *and* whose grain tag is its origin's tag: from
  a site, the grain it leaves and 1 in 63 of the others holding that point (1 in 2^b - 1 at b bits, below); from a
  field event, none. The rule is direction-free, so next-event estimation and phase sampling see the same medium and
  their MIS weights stay unbiased (a tag on scattered rays alone, with shadow rays skipping every ball holding their
  origin, read 1.0154 +- 0.0036 in the white furnace). The ball bounds the shift, not the scene's size: the search has
  its ``TAG_SEARCH`` tries however coarse its step, so a flight from far away (a camera far from a small cloud), whose
  step is t's ulp, finds its tag as a near one does, and no ray needs a ball grown by the shift. Measured
  (``bench_drjit_dense.py --far``: 8192 flights into the dense cloud below from points 2, 5, 20 and 100 extents from
  their site): no tag found 0, 0, 0 and 2.4e-4 of the searches (with the earlier bound, a share 2^-13 of the extent:
  0, 1.2e-4, 0.12 and 0.59); shifts of 22 steps (median) and at most 336 (at 100 extents 7.6e-6 a step: at most
  2.3e-3, a seventeenth of the grains' R). **Balls a few ulps wide.** A 6-bit tag needs a few hundred distinct float
  points along the ball's chord (a central hit holds ~2^(x + 24), x = e(R) - e(|p|_max), the difference of their
  binary exponents): below x = ``drjit_walk.TAG_FULL`` (-11; R / |p|_max below ~5e-4, far outside every shipped scene,
  whose x >= -9) the tag has fewer bits, ``drjit_walk.tag_bits``, a function of R and of the point alone (so the
  search at its candidate point and the rays leaving that point agree), chosen per cloud (``tag_thresholds``) to
  minimise the grains treated wrongly per site: the own grain's tag not found, against the other balls holding the
  point that a shorter tag skips (the mean number holding a point, ``holders``, from the balls' volumes over the
  cloud's). Measured (``bench_drjit_dense.py --offset 10000``: R = 0.04 at 10^4 units, x = -18, ~70 float points
  across; ``--far`` and renders at ``--sky 0``, against native exact): a sparse cloud (``--count 500``, 0.11 balls
  holding a point) gets 3 bits, no tag found at 2.3 % of the sites (6 bits: 50 %), the render -2.36 %, z -1.10 (6
  bits: +8.47 %, z +4.10; 64 seeds of 64 spp); the dense cloud (4.3 balls holding a point) gets 5 bits, no tag found
  at 28 % (50 %), the render +3.1 %, z +1.32 (6 bits: +2.1 %, z +0.71; 64 seeds of 32 spp): where balls a few ulps
  wide overlap, neither rule is exact. A flight from far away (its step t's ulp) has fewer points in the chord than
  ``tag_bits`` assumes: at 100 extents, 2.4e-4 of the dense cloud's searches fail. The remaining approximations: rays
  from other points (the camera, a surface, the medium's boundary) skip each grain whose ball holds their origin with
  probability 1/64 (2^-b), and a site's other holders are skipped with probability 1/63 (1 / (2^b - 1)) (the native
  kernel skips none of them); at a site of several coincident grains (projections within the site tolerance) the phase
  function mixes them all, as the native kernel's site does, but the rays leaving it skip only the picked grain (and
  coincident grains of its tag), where the native kernel skips the whole site; a search that finds no tag keeps the
  flight's t and the rays leaving it may meet the grain again: (63/64)^``TAG_SEARCH`` = 1e-7 where the ball's chord
  holds the tries (about 64 are needed), more at a grazing hit whose chord holds only a few steps (a share ~(32 delta
  / R)^2 of the hits: the 2.4e-4 at 100 extents); and the phase function's site search (below) admits a grain of p's
  tag crossing the ray within the search's largest shift, which mixes its phase function in (members per site in the
  dense cloud, where coincident grains are rare: 1.0015, 1.0016, 1.0044 and 1.0140 at 2, 5, 20 and 100 extents; none
  at a field event, whose tag no grain has). The site search grows R by its base tolerance, so a far grazing hit that
  the walk's rounding put inside the ball is found (without that, 1.2e-4 of the sites at 100 extents were missed and
  their paths ended there; now none). Measured (drjit against native exact, 2026-11-29): the dense cloud of
  ``scripts/bench/bench_drjit_dense.py`` (20 000 grains of reach 0.04 in the unit cube, about 5 other balls holding a
  site) +0.03 %, z +0.09 over 128 seeds (the direction tag, skipping every ball holding a site: +11.95 %, z +14.6 over
  32); the same seen from 60 units, its medium entered 56 units from the cloud (``--camera-distance 60``) +0.06 %, z
  +0.19 over 128 seeds; the white furnace (``bench_drjit_furnace.py --variants llvm_ad_rgb --seeds 4``) 0.99931 +-
  0.00065; the side-lit cloud (``bench_drjit_kernel.py --scenes sidelit --res 32 --spp 64 --seeds 12 --max-depth 2``)
  z +0.37, RMS/noise 0.93 (the direction tag: z -0.28, 0.94).
  ``EXCLUSION = "ball"`` (every ray skips every grain whose ball holds its origin, sites not moved) is kept for
  comparison: rays entering the cloud through the ball of a grain that straddles its box lose that grain
  (the side-lit cloud of ``scripts/bench/bench_lod.py``: 4.5 % darker than native, z -4.6, RMS/noise 3.65,
  ``scripts/bench/bench_drjit_kernel.py --scenes sidelit --exclusion ball``).
* **Sites and phase function.** A free flight stops at the first grain that interacts; the phase function finds the
  site from ``mei.p`` and ``mei.wi`` alone: the grains whose ball the incoming ray (through p along -wi) crosses and
  whose centre projects on it within ``4 coincide + 1e-6 |p|_max`` of p (the core's ``DiscreteMedium::site_near``;
  ``coincide`` = 1e-6 of the grains' extent, ``render/discrete/build.rs``) and ``FLIGHT_ROUNDING`` steps of the tag
  search at ``mei.t`` (the flight's own rounding of t, which beyond ~70 extents from the ray's origin outgrows the
  rest; R is grown by the same tolerance), or within that plus the tag search's largest shift where p carries the
  grain's tag (the picked grain, moved along the ray by ``_tag_search``; the bound, ``_shift_bound``, rebuilt
  from ``mei.t`` and p, since the step grows with t, and at most the grain's R, since the search keeps p inside
  its ball; the tag also keeps out most grains that merely pass near).
  They are in the cells of each size class within its reach of p. Per channel c, with tau_j the grains' grey optical
  depths and a_jc their bins' albedos (times ``albedo_scale``): value_c = sum_j tau_j a_jc f_jc(mu) / sum_j
  tau_j (the site's albedo times its mixture f_c = sum_j tau_j a_jc f_jc / sum_j tau_j a_jc), pdf = the mean
  over channels of f_c, mu = cos of the angle between -wi and wo. ``sample`` picks a channel uniformly
  (``sample1``), a grain by tau_j a_jc (the rest of ``sample1``), mu from the grain's bin's table by inverting
  its CDF (piecewise linear f in mu, as ``PhaseTable`` in ``rust/motes-core/src/ensemble/phase_table.rs``),
  phi from ``sample2.y``, and returns value / pdf with the mixture's pdf (a second walk of the site, or at a
  site of one grain its bin's tables alone): sampling and evaluation agree (``tests/test_drjit_medium.py``,
  chi-square). The native kernel picks channels by the path's throughput
  (remembered with the event); here uniformly: the same expectation, other noise in coloured media (a channel
  whose grains all have albedo 0 ends the paths that pick it: unbiased, noisier; the pdf counts it as 0).
* Tables: each bin's phase tables at every tabulated wavelength as the core prepared them
  (``DiscreteMedium.flat_tables``: nodes in mu, f and CDF normalised). RGB channels read their own
  wavelength's (mono: the middle one, as ``_bridge.channel_wavelengths``); in spectral variants each of the
  path's wavelengths (``mei.wavelengths``) reads the two tabulated around it, albedo and phase function interpolated
  linearly in wavelength and clamped at the ends (``DiscreteMedium::bracket``, ``bin_albedo``, ``bin_phase``), and
  ``sample`` draws mu from the lower or the upper table with the interpolation's weights, by the rest of ``sample1``
  after the grain's pick (``mixture_sample``).
* Polarised variants: where the grains' phase function is their own (the core's ``polarizes``), each table also
  carries F12/F11, F33/F11 and F34/F11 on its nodes (``DiscreteMedium.flat_tables``, ``mueller.rs``); a site
  mixes its grains' elements F11, F12, F33, F34 as it mixes F11, and the phase function returns that matrix
  rotated into Mitsuba's Stokes frames (``_bridge.mueller_of``, as the native plugin and the evaluated path
  build it); sampling draws from F11 alone, as unpolarised. Otherwise (a user's phase function,
  ``phase_model = "hg"``) a depolarizer.
"""

from __future__ import annotations

import math
import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from ..drjit_field import DrJitField
from ..drjit_procedural import DrJitProcedural
from ..drjit_walk import (FIELD_TAG, TAG_MASK, DrJitGrid, fold_key, grain_hash, largest, origin_hash,
                          point_exponent, tags_agree)
from ._bridge import depolarized, mueller_of

#: What ``kernel`` takes, and its default (``default_kernel``: ``drjit`` in CUDA variants, the only one there).
KERNELS = ("native", "drjit")
DEFAULT_KERNEL = "native"
#: ``cells_per_particle`` where ``kernel = "drjit"`` (the native kernel's 0.125 elsewhere): the Dr.Jit walk tests
#: every grain of a cell it passes near, so finer cells pay (``scenes_xml/cornell.xml``, 1e5 grains of reach 0.7 in
#: a room of 54 units, 2e5 flights from random points in it: 0.125 gave cells of 3.7 units and 2.0 s; 1: 1.1 s;
#: 4: 1.1 s; 16: 1.7 s; 2 cores).
DRJIT_CELLS_PER_PARTICLE = 2.0
#: The variants ``kernel = "drjit"`` renders in: the JIT ones.
DRJIT_VARIANTS = tuple(f"{b}_ad_{c}" for b in ("llvm", "cuda")
                       for c in ("rgb", "mono", "spectral", "mono_polarized", "spectral_polarized"))
#: The core's coincidence window as a share of the grains' extent (``event_geometry`` in
#: ``rust/motes-core/src/render/discrete/build.rs``) and the site search's tolerance around it
#: (``DiscreteMedium::site_near`` in ``phase.rs``): 4 coincide + ``SITE_RELATIVE`` |p|_max.
COINCIDE_SHARE = 1e-6
SITE_COINCIDE = 4.0
SITE_RELATIVE = 1e-6
#: The origin tag (module docs, "Parent exclusion"): ``intersect_aabb`` moves a site along its ray, at most
#: ``TAG_SEARCH`` tries (k = 0, 1, -1, 2, ...: at most 512 steps either way), each a step of about an ulp of its
#: largest coordinate (or of t, where coarser), to the first point inside its grain's ball whose ``origin_tag``
#: is its grain's ``grain_tag``: about 64 tries are needed, (63/64)^1024 = 1e-7 fail where the ball's chord
#: holds them all. The site search allows the largest such shift (``_shift_bound``), so more tries would admit
#: more grains that merely pass near a site.
TAG_SEARCH = 1024
#: Steps of the tag search (``DrJitKernel._tag_step``) that cover a flight's rounding of its t (t_enter + the
#: centre's projection, each rounded: about an ulp of t each): the site search's tolerance adds them.
FLIGHT_ROUNDING = 4
#: ``origin`` (the rule above) or ``ball``: every ray skips every grain whose ball holds its origin, and sites
#: stay where the flight found them (for comparison: ``scripts/bench/bench_drjit_kernel.py --exclusion ball``).
EXCLUSION = "origin"


def one_minus_cos(a, b):
    """1 - a.b of unit vectors ``a``, ``b`` as |a - b|^2 / 2: no cancellation near the forward direction (the
    phase tables' variable, ``DrJitKernel._tables``)."""
    v = a - b
    return dr.clip(0.5 * dr.dot(v, v), 0.0, 2.0)


def bits(x):
    """A float's bits (``mi.UInt32``): what the ray's and the site's hashes read."""
    return dr.reinterpret_array(mi.UInt32, mi.Float(x))


def default_kernel(variant: str) -> str:
    """``kernel``'s default in ``variant``: ``drjit`` in CUDA variants (a CUDA kernel cannot call the Rust core),
    else ``DEFAULT_KERNEL``."""
    return "drjit" if variant.startswith("cuda_") else DEFAULT_KERNEL


def _jit_bytes(arrays: dict) -> int:
    """Bytes of the JIT arrays among ``arrays``' values (4 a 32-bit entry, 8 a 64-bit one, 1 a mask's)."""
    size = {dr.VarType.Float64: 8, dr.VarType.UInt64: 8, dr.VarType.Int64: 8, dr.VarType.Bool: 1}

    def of(v) -> int:
        if isinstance(v, (list, tuple)):
            return sum(of(x) for x in v)
        if isinstance(v, dict):
            return sum(of(x) for x in v.values())
        if dr.is_array_v(v) and dr.is_jit_v(v) and dr.depth_v(v) == 1:
            return dr.width(v) * size.get(dr.type_v(v), 4)
        return 0

    return of(arrays)


def kernel_problem(kernel: str, variant: str) -> str | None:
    """Why ``kernel`` cannot render in ``variant`` (one sentence), or None."""
    if kernel == "native" and variant.startswith("cuda_"):
        return (f"discrete medium: kernel = native cannot render in {variant} (the Rust walk runs on the host and a "
                "CUDA kernel cannot call it): use kernel = drjit, the default there")
    if kernel != "drjit":
        return None
    if variant not in DRJIT_VARIANTS:
        return (f"discrete medium: kernel = drjit renders in the JIT variants (llvm_ad_*, cuda_ad_*), not {variant} "
                "(use kernel = native)")
    return None


class DrJitKernel:
    """The medium's and its phase function's calls in Dr.Jit types over a ``motes.DiscreteMedium`` (module docs).
    ``source``: the medium's data, or a ``_scene.PendingFill`` that makes it (built at the first call)."""

    def __init__(self, source, seed: int = 0, majorant: float = 1e20):
        self._source = source
        self.seed = int(seed)
        self.majorant = float(majorant)
        self._ready = False

    # -- set-up ------------------------------------------------------------------------------------
    def data(self):
        s = self._source
        return s.result() if hasattr(s, "result") else s

    def ready(self) -> "DrJitKernel":
        if not self._ready:
            self._upload(self.data())
            self._ready = True
        return self

    def device_bytes(self) -> dict:
        """Bytes of the arrays uploaded (once per load) to the variant's device: "grains" (the walk's per-grain
        and per-cell arrays and the size classes' tables), "field" (the continuous classes' field: sigma and
        entry starts per cell, bin and share per entry; 0 without one), "tables" (the bins' phase tables and
        albedos), "total", and "per_grain" (grains / count; None for a procedural cloud, which stores none, and
        where every class is continuous); empty before the first call uploads them."""
        if not self._ready:
            return {}
        walked = self.grid if self.proc is None else self.proc
        grains = 0 if walked is None else _jit_bytes(vars(walked))
        field = 0 if self.field is None else _jit_bytes(vars(self.field))
        names = ("_x", "_f", "_cdf", "_off", "_cnt", "_albedo") + (("_ratios",) if self.polarizing else ())
        tables = _jit_bytes({k: getattr(self, k) for k in names})
        per_grain = None if self.grid is None else grains / max(self.grid.count, 1)  # procedural: none stored
        return {"grains": grains, "field": field, "tables": tables, "total": grains + field + tables,
                "per_grain": per_grain}

    def summary(self) -> str:
        """One line: the kernel and, once uploaded, what it holds on the device."""
        b = self.device_bytes()
        if not b:
            return "kernel = drjit (arrays not uploaded yet)"
        field = "" if self.field is None else (f", a continuous field of {self.field.cells} cells "
                                               f"({b['field'] / 2**20:.2f} MiB)")
        if self.proc is not None:
            return (f"kernel = drjit: a procedural cloud regenerated where rays need it, {b['total'] / 2**20:.1f} MiB "
                    f"on the device ({b['tables'] / 2**20:.2f} MiB of tables){field}")
        if self.grid is None:
            return (f"kernel = drjit: no grains walked{field}, {b['total'] / 2**20:.1f} MiB on the device "
                    f"({b['tables'] / 2**20:.2f} MiB of tables)")
        return (f"kernel = drjit: {self.grid.count} grains, {b['total'] / 2**20:.1f} MiB on the device "
                f"({b['per_grain']:.1f} B a grain with its cells, {b['tables'] / 2**20:.2f} MiB of tables){field}")

    def _upload(self, data) -> None:
        self.grid = self.proc = self.field = None
        # The continuous size classes' field (module docs, "Continuous size classes"): a stored set's, or a
        # procedural cloud's expected extinction of its continuous classes (at rest, as the native kernel's).
        f = data.core.flat_field()
        self.field = None if f is None else DrJitField(f)
        if data.core.procedural_cloud:
            self.proc = self._procedural_grains(data.core)
            if self.proc is None and self.field is None:
                raise ValueError("discrete medium: kernel = drjit found neither grains to regenerate nor a continuous "
                                 "field in this procedural cloud (an empty medium)")
            extent = self.proc.extent() if self.proc is not None else self._field_extent()
        else:
            a = data.core.flat_arrays()
            if a is None and self.field is None:
                raise ValueError("discrete medium: kernel = drjit found neither grains to walk nor a continuous "
                                 "field (an empty medium)")
            self.grid = None if a is None else DrJitGrid(a)
            spheres = np.zeros((0, 4)) if a is None else np.asarray(a["spheres"], dtype=np.float64).reshape(-1, 4)
            if spheres.shape[0]:
                extent = float(np.max(spheres[:, :3].max(axis=0) - spheres[:, :3].min(axis=0)) + spheres[:, 3].max())
            else:  # no grains: the field's box
                extent = self._field_extent()
        self.extent = max(extent, 1e-30)
        self.coincide = COINCIDE_SHARE * self.extent
        self._tables(data)
        self.set_albedo_scale(data.core.albedo_scale)
        self._seed = [dr.opaque(mi.UInt32, self.seed & 0xFFFFFFFF),
                      dr.opaque(mi.UInt32, (self.seed >> 32) & 0xFFFFFFFF)]

    def _procedural_grains(self, core):
        """A procedural cloud's discrete grains, regenerated by ``DrJitProcedural`` (None where every class is
        continuous: the field alone is walked, as a stored set's)."""
        export = core.procedural_export()
        if export is None:
            return None
        try:
            return DrJitProcedural(export)
        except ValueError as e:  # a grid density (its field alone, every class continuous, is walked)
            raise ValueError(f"discrete medium: kernel = drjit cannot render this procedural cloud ({e}): use "
                             "kernel = native") from None

    def _field_extent(self) -> float:
        """The largest side of the continuous field's box (0 without one): the grains' extent where none is
        walked."""
        return 0.0 if self.field is None else float(np.max(self.field.cell * self.field.dims))

    def _tables(self, data) -> None:
        """Per (bin, tabulated wavelength): the phase table (the core's nodes: mu ascending, f and CDF normalised,
        ``DiscreteMedium.flat_tables``) and the albedo, flat, table ``b * n_lam + k``; and each channel's
        wavelength as the tables see it (``_waves``)."""
        lam_nm = np.asarray(data.wavelength_um, dtype=np.float64) * 1e3  # ascending (``discrete.py``)
        n_lam = lam_nm.size
        self.n_lam = n_lam
        self._lam_nm = [float(x) for x in lam_nm]
        if mi.is_spectral:
            self.channels = dr.size_v(mi.UnpolarizedSpectrum)
            self._rows = None  # per lane, from the path's wavelengths (``_waves``)
        else:
            chan_nm = np.asarray(data.channel_wavelength_nm, dtype=np.float64)
            if not mi.is_rgb:  # monochrome: the middle tabulated wavelength (``_bridge.channel_wavelengths``)
                chan_nm = chan_nm[[chan_nm.size // 2]]
            rows = []
            for nm in chan_nm:
                k = int(np.argmin(np.abs(lam_nm - nm)))
                if abs(lam_nm[k] - nm) > 1e-6 * nm:
                    raise ValueError(f"discrete medium: kernel = drjit needs a table at each channel's wavelength "
                                     f"({nm} nm)")
                rows.append(k)
            self.channels = len(rows)
            self._rows = rows
        t = data.core.flat_tables()  # the core's prepared tables (``PhaseTable::nodes``)
        off = np.asarray(t["offset"], dtype=np.int64)
        if (off.size - 1) % n_lam:  # one table per bin and tabulated wavelength, bin-major
            raise ValueError(f"discrete medium: {off.size - 1} phase tables at {n_lam} wavelengths")
        cnt = np.diff(off)
        # Nodes as 1 - mu (descending along a table), from the core's double precision: a grain's diffraction peak
        # lies within 1e-8 of mu = 1, where single-precision mu has a step of 6e-8 (a cornell grain's table:
        # 240 of 1802 nodes merged, its integral 0.63; fireflies), and 1 - mu keeps its relative precision.
        x = (1.0 - np.asarray(t["mu"], dtype=np.float64)).astype(np.float32)
        self._x = mi.Float(x)
        # A segment whose nodes merge in single precision but which holds probability would be sampled as a point
        # the evaluation cannot see (none in 1 - mu for grains of 0.5-1000 um; in mu, 108-720 per table).
        cdf = np.asarray(t["cdf"], dtype=np.float64)
        merged = (np.diff(x) == 0) & (np.diff(cdf) > 0)
        merged[off[1:-1] - 1] = False  # the last node of one table and the first of the next
        if merged.any():
            warnings.warn(f"discrete medium (kernel = drjit): {int(merged.sum())} phase-table segments merge in single "
                          "precision; sampling and evaluation disagree within them", stacklevel=2)
        self._f = mi.Float(np.asarray(t["f"], dtype=np.float32))
        self._cdf = mi.Float(np.asarray(t["cdf"], dtype=np.float32))
        self._off = mi.UInt32(off[:-1].astype(np.uint32))
        self._cnt = mi.UInt32(cnt.astype(np.uint32))
        self._albedo = mi.Float(np.asarray(t["albedo"], dtype=np.float32))
        # Polarised variants, grains' own phase functions: F12/F11, F33/F11, F34/F11 on each table's nodes
        # (``mueller.rs``; 0 where a bin depolarises), elements F11, F12, F33, F34 per channel (``E``).
        self.polarizing = bool(mi.is_polarized) and bool(data.core.polarizes)
        self.E = 4 if self.polarizing else 1
        if self.polarizing:
            self._ratios = mi.Float(np.asarray(t["mueller"], dtype=np.float32))
        self._steps = max(1, math.ceil(math.log2(max(cnt))))  # bisection steps over the longest table

    def _waves(self, mei):
        """Per channel, the tables' bracket of its wavelength: (lower row, upper row, weight of the upper), as
        ``DiscreteMedium::bracket`` (clamped to the tabulated range). RGB and mono: each channel's own row
        (weight None: no interpolation); spectral: per lane, from ``mei.wavelengths``."""
        if self._rows is not None:
            return [(k, k, None) for k in self._rows]
        lam = self._lam_nm
        out = []
        for c in range(self.channels):
            l = mi.Float(mei.wavelengths[c])
            above = dr.zeros(mi.UInt32, dr.width(l))  # tabulated wavelengths <= l (``partition_point``)
            for x in lam:
                above += dr.select(l >= x, 1, 0)
            k1 = dr.minimum(above, len(lam) - 1)
            k0 = dr.select(above > 0, above - 1, 0)
            lo, hi = dr.gather(mi.Float, mi.Float(lam), k0), dr.gather(mi.Float, mi.Float(lam), k1)
            inside = (above > 0) & (above < len(lam))
            w = dr.select(inside, (l - lo) / dr.select(inside, hi - lo, 1.0), 0.0)
            out.append((k0, k1, dr.clip(w, 0.0, 1.0)))  # below: (0, 0, 0); above: (n - 1, n - 1, 0)
        return out

    def _bin_albedo(self, b, wave, active):
        """A bin's albedo at a channel's bracket ``wave`` (without the albedo scale): ``bin_albedo``."""
        k0, k1, w = wave
        a0 = dr.gather(mi.Float, self._albedo, b * self.n_lam + k0, active)
        if w is None:
            return a0
        return (1 - w) * a0 + w * dr.gather(mi.Float, self._albedo, b * self.n_lam + k1, active)

    def _channel_wave(self, waves, c):
        """The bracket of channel ``c`` (per lane) of ``waves``."""
        k0, k1, w = waves[0]
        for j in range(1, len(waves)):
            pick = c == j
            k0 = dr.select(pick, waves[j][0], k0)
            k1 = dr.select(pick, waves[j][1], k1)
            w = None if w is None else dr.select(pick, waves[j][2], w)
        return k0, k1, w

    def _bin_elements(self, b, wave, one_minus_mu, active):
        """A bin's elements at ``wave`` and 1 - mu = ``one_minus_mu`` (``E`` of them: F11, the phase function, as
        ``bin_phase``; and
        F12, F33, F34 where polarising, as ``bin_elements``): the two rows' tables, interpolated."""
        k0, k1, w = wave
        e0 = self._table_elements(b * self.n_lam + k0, one_minus_mu, active)
        if w is None:
            return e0
        e1 = self._table_elements(b * self.n_lam + k1, one_minus_mu, active & (w > 0))
        return [(1 - w) * x0 + w * x1 for x0, x1 in zip(e0, e1)]

    def _spectrum(self, elements, ctx, mei, wo):
        """The phase function's value from its elements per channel (``elements[c][k]``): the channels'
        ``UnpolarizedSpectrum``; in polarised variants the Mueller matrix in Mitsuba's Stokes frames
        (``_bridge.mueller_of``, as the native plugin builds it) or, where the grains depolarise, a depolarizer."""
        per_k = [mi.UnpolarizedSpectrum(*[elements[c][k] for c in range(self.channels)]) for k in range(self.E)]
        if self.polarizing:
            return mueller_of(per_k, dr.width(per_k[0][0]), ctx, mei, wo)
        return depolarized(per_k[0])

    def set_albedo_scale(self, scale: float) -> None:
        """The medium's ``albedo_scale`` (read at the next trace)."""
        self._scale = dr.opaque(mi.Float, float(scale))

    # -- medium ------------------------------------------------------------------------------------
    def _ray_seed(self, ray):
        """A per-ray seed: TEA over the bits of the ray's origin, direction and maxt and the medium's seed."""
        h0, h1 = mi.sample_tea_32(bits(ray.o.x) ^ self._seed[0], bits(ray.o.y) ^ self._seed[1], 4)
        h0, h1 = mi.sample_tea_32(h0 ^ bits(ray.o.z), h1 ^ bits(ray.d.x), 4)
        h0, h1 = mi.sample_tea_32(h0 ^ bits(ray.d.y), h1 ^ bits(ray.d.z), 4)
        h0, _ = mi.sample_tea_32(h0 ^ bits(ray.maxt), h1, 4)
        return h0

    def _ray_seed_high(self, low):
        """The high 32 bits of a procedural cloud's 64-bit flight seed, a hash of the low 32 (``_ray_seed``): 32
        bits of entropy, spread over the 64 its grains' streams read."""
        h0, _ = mi.sample_tea_32(low, self._seed[1] ^ 0x9E3779B9, 4)
        return h0

    @staticmethod
    def _tag_step(t, m, dm):
        """The tag search's step in t at distance ``t`` along a ray whose direction's largest component is ``dm``,
        at a point whose largest coordinate's magnitude is ``m``: an ulp of m over dm (each step moves that
        coordinate by at least an ulp, so every step reaches a new point) or an ulp of t where that is coarser (a
        flight from far away: t + delta must differ from t)."""
        F, U = mi.Float, mi.UInt32
        ulp = lambda x: dr.reinterpret_array(F, dr.reinterpret_array(U, F(x)) & 0x7F800000) * 2.0**-23
        return dr.maximum(dr.maximum(ulp(m) / dr.maximum(F(dm), 1e-30), ulp(t)), 1e-38)

    @staticmethod
    def _event_t(t):
        """An event's distance along its ray as the site search reads it (``mei.t``): non-finite (no event) as 0."""
        t = mi.Float(t)
        return dr.select(dr.isfinite(t), dr.abs(t), 0.0)

    @classmethod
    def _shift_bound(cls, t, p, d):
        """A bound on a site's shift along its ray (``_tag_search``: at most ``TAG_SEARCH`` / 2 steps from the
        flight's t) rebuilt from the site alone: its distance ``t`` (``mei.t``, the shifted t*) and point ``p`` on
        its ray along ``d``. The search's step was taken at the flight's t and point, within 512 of its steps
        of t*, which is at most twice the step at t*: so within ``reach`` = (``TAG_SEARCH`` + 2
        ``FLIGHT_ROUNDING``) steps at t*, and the step at t* + reach, |p|_max + reach (ulps grow with magnitude)
        bounds the search's. ``FLIGHT_ROUNDING`` steps more: the flight's own rounding of t."""
        t = cls._event_t(t)
        m, dm = cls._largest(p), cls._largest(d)
        reach = (TAG_SEARCH + 2 * FLIGHT_ROUNDING) * cls._tag_step(t, m, dm)
        return (TAG_SEARCH // 2 + FLIGHT_ROUNDING) * cls._tag_step(t + reach, m + reach, dm)

    @staticmethod
    def _largest(v):
        return largest(v.x, v.y, v.z)

    @staticmethod
    def _inside(q, centre, radius):
        """Whether point ``q`` lies inside the ball (``centre`` [x, y, z], ``radius``), in single precision: the
        difference of nearby floats is exact, so this is the distance the walk's exclusion test computes from a
        ray starting at ``q``, to ~1e-7 (its ``EXCLUDE_MARGIN`` absorbs that)."""
        F = mi.Float
        v = [F(centre[0]) - q.x, F(centre[1]) - q.y, F(centre[2]) - q.z]
        r = F(radius)
        return v[0] * v[0] + v[1] * v[1] + v[2] * v[2] < r * r

    @dr.syntax
    def _tag_search(self, ray, t, g_hash, field, ball, active, end):
        """The t* near the flight's ``t`` whose point fma(d, t*, o) (Mitsuba's ``ray(t)``, the ``mei.p`` the phase
        function and the rays leaving the site see: the majorant's step adds nothing to t*) carries the tag of the
        picked grain (its ``grain_hash`` ``g_hash``, ``tags_agree``) and lies inside the grain's ``ball`` (centre, R
        as the walk read them), or where ``field`` (a field event: no grain, no ball) carries ``FIELD_TAG``:
        t + k delta for k = 0, 1, -1, 2, -2, ..., delta ``_tag_step``, at most ``TAG_SEARCH`` tries, and before
        ``end``, the end of the segment the walk searched (Mitsuba keeps an event at t* < maxt; with a
        continuous field, the grains' event must stay before the field's). The ball, not a share of the scene,
        bounds the shift: a ray from t* then skips its grain by the plain ball test and the tag, and a flight
        from far away (a coarse step) still has its tries. t where none, (1 - 2^-b)^tries (module docs)."""
        F, U = mi.Float, mi.UInt32
        o, d = mi.Point3f(ray.o), mi.Vector3f(ray.d)
        t = F(t)
        g_hash, field = U(g_hash), mi.Bool(field)
        walked = self.grid if self.proc is None else self.proc  # a field alone: field events only
        thresholds = walked.tag_thresholds if walked is not None else None
        centre, radius = ball
        radius = F(radius)

        def carries(q):  # whether point q carries the tag sought (the grain's at q's tag bits, or the field's)
            h = origin_hash(q.x, q.y, q.z)
            return dr.select(field, (h & TAG_MASK) == FIELD_TAG,
                             tags_agree(h, g_hash, radius, point_exponent(q.x, q.y, q.z), thresholds))

        p = dr.fma(d, t, o)
        delta = self._tag_step(t, self._largest(p), self._largest(d))
        best = F(t)
        found = ~mi.Bool(active) | (carries(p) & (field | self._inside(p, centre, radius)))
        i = dr.zeros(U, dr.width(best))
        while ~found & (i < TAG_SEARCH):
            i += 1
            k = dr.select((i & 1) == 1, F((i + 1) >> 1), -F(i >> 1))
            tk = dr.fma(k, delta, t)
            pk = dr.fma(d, tk, o)
            ok = (tk > 0) & (tk < end) & (field | self._inside(pk, centre, radius))
            hit = ok & carries(pk)
            best = dr.select(hit, tk, best)
            # Both sides spent once a step reaches past the ball's diameter (no chord is longer).
            found |= hit | (~field & (F((i + 1) >> 1) * delta > 2 * radius))
        return best

    def _field_flight(self, ray, seed):
        """The continuous field's exact free flight on [0, maxt) (``DrJitField.sample_free_flight``, its numbers
        ``seed``, a ``mi.UInt32``, hashed with the field's own key): (its t, whether it hits, the end of the
        segment the grains are then walked on: its t where it hits, else maxt); (None, None, maxt) without a
        field."""
        maxt = mi.Float(ray.maxt)
        if self.field is None:
            return None, None, maxt
        t_f, hit_f = self.field.sample_free_flight(ray.o, ray.d, ray.maxt, seed)
        return t_f, hit_f, dr.select(hit_f, t_f, maxt)

    @staticmethod
    def _nearer(t, valid, t_f, hit_f):
        """The nearer of the grains' interaction (``t``, ``valid``; walked up to the field's flight, so nearer
        where valid) and the field's (``t_f``, ``hit_f``; None: no field): the two processes are independent, so
        the first interaction of their union is the first of either (``continuous/mod.rs``)."""
        if t_f is None:
            return t, valid
        return dr.select(valid, t, t_f), valid | hit_f

    def intersect_aabb(self, ray):
        self.ready()
        # Parent exclusion (module docs): every ray skips the grains whose ball holds its origin and whose grain
        # tag is its origin's tag; ``ball``: every grain whose ball holds it.
        tagged = EXCLUSION == "origin"
        # ``end``: the end of the segment the grains are walked on (the field's flight, else maxt).
        if self.proc is not None:
            # The continuous classes' field first, then the regenerated grains up to its flight (as the stored
            # branch below): the field's numbers hash the low 32 bits of the grains' 64-bit seed apart.
            low = self._ray_seed(ray)
            t_f, hit_f, end = self._field_flight(ray, low)
            seed = mi.UInt64(low) | (mi.UInt64(self._ray_seed_high(low)) << 32)
            t, key, _, valid, ball = self.proc.sample_free_flight(ray.o, ray.d, 0.0, end, seed, exclude_origin=True,
                                                                  tagged=tagged, want_ball=True)
            t, grain, ident = mi.Float(t), mi.Bool(valid), fold_key(key)
            t, valid = self._nearer(t, valid, t_f, hit_f)
            ball = (ball[0], mi.Float(ball[1]))
        else:
            # Continuous size classes: the field's exact free flight first, then the grains up to its distance;
            # the two processes are independent, so the nearer interaction wins (``continuous/mod.rs``, as the
            # native kernel's ``discrete/flight.rs``). Their numbers: the same ray seed, hashed apart.
            seed = self._ray_seed(ray)
            t_f, hit_f, end = self._field_flight(ray, seed)
            if self.grid is not None:
                t, _, valid, ident, *ball = self.grid.sample_free_flight(ray.o, ray.d, end, seed, exclude_origin=True,
                                                                         want_index=False, tagged=tagged,
                                                                         want_grain=True, want_ball=tagged)
                ball = ball[0] if tagged else None
            else:
                t, valid = dr.full(mi.Float, dr.inf, dr.width(end)), dr.zeros(mi.Bool, dr.width(end))
                ident = dr.zeros(mi.UInt32, dr.width(end))
                ball = ([mi.Float(0.0)] * 3, mi.Float(0.0))
            t, grain = mi.Float(t), mi.Bool(valid)
            t, valid = self._nearer(t, valid, t_f, hit_f)  # a field event keeps its point (no grain to tag)
        if tagged:
            # A grain's event to a point of its grain's tag inside its ball; a field event (valid, no grain) to a
            # point of ``FIELD_TAG``, no grain's: the rays leaving it skip no grain and its site admits none by tag
            # (module docs). A field event may move either way (its segment's end is maxt; the grains before it
            # were walked to its t, and a few ulps past it hold none but with probability ~ulp / spacing).
            field_event = valid & ~grain
            end = dr.select(grain, end, mi.Float(ray.maxt))
            with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
                t = self._tag_search(ray, t, grain_hash(ident), field_event, ball, grain | field_event, end)
        return valid, dr.select(valid, mi.Float(t), dr.inf), dr.select(valid, dr.inf, -dr.inf)

    def get_majorant(self, mei, active=True):
        return mi.UnpolarizedSpectrum(dr.select(active, mi.Float(self.majorant), 0.0))

    def get_scattering_coefficients(self, mei, active=True):
        sigma_t = mi.UnpolarizedSpectrum(dr.select(active, mi.Float(self.majorant), 0.0))
        return sigma_t, mi.UnpolarizedSpectrum(0.0), sigma_t

    # -- phase function ----------------------------------------------------------------------------
    def eval_pdf(self, ctx, mei, wo, active=True):
        self.ready()
        d_in = -mi.Vector3f(mei.wi)
        elements, pdf, _ = self._site(mi.Point3f(mei.p), d_in, self._waves(mei),
                                      one_minus_mu=one_minus_cos(mi.Vector3f(wo), d_in), active=active, t=mei.t)
        return self._spectrum(elements, ctx, mei, wo), pdf

    def sample(self, ctx, mei, sample1, sample2, active=True):
        self.ready()
        d_in = -mi.Vector3f(mei.wi)
        ch = self.channels
        u1 = mi.Float(sample1) * ch
        c = mi.UInt32(dr.minimum(dr.floor(u1), ch - 1))
        u = dr.clip(u1 - mi.Float(c), 0.0, 0.99999994)  # below 1: the reservoir picks where u < a share
        p = mi.Point3f(mei.p)
        waves = self._waves(mei)
        _, members, (b, u) = self._site(p, d_in, waves, pick=(c, u), active=active, t=mei.t)
        valid = b != 0xFFFFFFFF
        # The picked grain's table at the picked channel: its lower or upper wavelength's by the rest of
        # sample1 (``mixture_sample``).
        k0, k1, w = self._channel_wave(waves, c)
        row = k0 if w is None else dr.select(u < 1 - w, k0, k1)
        one_minus_mu = self._table_sample(b * self.n_lam + row, mi.Float(sample2.x), valid)
        phi = 2 * dr.pi * mi.Float(sample2.y)
        st = dr.safe_sqrt(one_minus_mu * (2 - one_minus_mu))  # sin(theta), exact near the forward peak
        sp, cp = dr.sincos(phi)
        wo = mi.Frame3f(d_in).to_world(mi.Vector3f(st * cp, st * sp, 1 - one_minus_mu))
        # A site of one grain (most) needs no second walk: its bin's tables at one_minus_mu, times its albedo.
        one = valid & (members == 1)
        elements, pdf = self._mixture(p, d_in, waves, one_minus_mu, active=valid & ~one, t=mei.t)
        elements, pdf = self._one_grain(b, waves, one_minus_mu, one, elements, pdf)
        value = self._spectrum(elements, ctx, mei, wo)
        ok = valid & (pdf > 0)
        weight = dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)
        return wo, weight, dr.select(ok, pdf, 0.0)

    # -- tables ------------------------------------------------------------------------------------
    def _segment(self, keys, tid, x, active, descending=False):
        """The node i of table ``tid`` with keys[i] <= x < keys[i + 1] (clamped to its segments), by bisection;
        ``descending`` keys: keys[i] >= x > keys[i + 1]."""
        off = dr.gather(mi.UInt32, self._off, tid, active)
        n = dr.gather(mi.UInt32, self._cnt, tid, active)
        lo, hi = mi.UInt32(0), dr.select(active, n - 1, 1)  # x between keys[off + lo] and keys[off + hi] (invariant)
        for _ in range(self._steps):
            mid = (lo + hi) >> 1
            go = hi - lo > 1
            key = dr.gather(mi.Float, keys, off + mid, active & go)
            right = key >= x if descending else key <= x
            lo = dr.select(go & right, mid, lo)
            hi = dr.select(go & ~right, mid, hi)
        return off + lo

    def _table_elements(self, tid, one_minus_mu, active):
        """Table ``tid``'s elements at 1 - mu = ``one_minus_mu`` (``E`` of them): f, and where polarising f times each
        ratio, all interpolated linearly between the nodes around it (``PhaseTable::eval_at``,
        ``MuellerRatios::at``)."""
        i = self._segment(self._x, tid, one_minus_mu, active, descending=True)
        x0, x1 = dr.gather(mi.Float, self._x, i, active), dr.gather(mi.Float, self._x, i + 1, active)
        f0, f1 = dr.gather(mi.Float, self._f, i, active), dr.gather(mi.Float, self._f, i + 1, active)
        t = dr.clip(dr.select(x0 > x1, (x0 - one_minus_mu) / (x0 - x1), 0.0), 0.0, 1.0)
        f = dr.select(active, f0 + t * (f1 - f0), 0.0)
        if not self.polarizing:
            return [f]
        out = [f]
        for k in range(3):
            r0 = dr.gather(mi.Float, self._ratios, 3 * i + k, active)
            r1 = dr.gather(mi.Float, self._ratios, 3 * i + 3 + k, active)
            out.append(f * (r0 + t * (r1 - r0)))
        return out

    def _table_sample(self, tid, u, active):
        """1 - mu of the mu with CDF(mu) = u in table ``tid`` (``PhaseTable::sample_located``: the quadratic CDF
        inverted)."""
        u = dr.clip(u, 0.0, 1.0)
        i = self._segment(self._cdf, tid, u, active)
        c0 = dr.gather(mi.Float, self._cdf, i, active)
        x0, x1 = dr.gather(mi.Float, self._x, i, active), dr.gather(mi.Float, self._x, i + 1, active)
        f0, f1 = dr.gather(mi.Float, self._f, i, active), dr.gather(mi.Float, self._f, i + 1, active)
        dm = x0 - x1  # the segment's width in mu
        q = 2 * dr.pi * dm
        a, b = q * f0, q * (f1 - f0)
        target = u - c0
        disc = dr.maximum(a * a + 2 * b * target, 0.0)
        lin = dr.abs(b) < 1e-6 * dr.abs(a)
        t = dr.select(lin, dr.select(a > 0, target / dr.select(a > 0, a, 1.0), 0.5),
                      2 * target / dr.select(a + dr.sqrt(disc) > 0, a + dr.sqrt(disc), 1.0))
        t = dr.select(target > 0, dr.clip(t, 0.0, 1.0), 0.0)
        return dr.clip(x0 - t * dm, 0.0, 2.0)

    # -- the site ----------------------------------------------------------------------------------
    def _site_sums(self, p, d_in, waves, one_minus_mu, pick, active, t):
        """The walk of ``_site`` over the grains that could be part of the site at ``p``, ``t`` along its ray
        (``mei.t``: what bounds the tag search's shift, ``_shift_bound``) (stored: the cells within
        reach of ``p`` per size class; procedural: the tiles within the halo of ``p``'s, regenerated): per
        channel sum tau_j a_jc and sum tau_j a_jc f_jc(one_minus_mu), and sum tau_j (``one_minus_mu`` given); the
        picked grain's bin and the uniform left (``pick`` given); or (neither) the number of the site's grains and the
        first one's bin. Where no grain is found and ``p``'s field cell has sigma_t > 0 (a field event), the same over
        the cell's entries, their shares s_i for tau_j."""
        F, U = mi.Float, mi.UInt32
        ch = self.channels
        n = max(dr.width(p), dr.width(d_in), 1 if one_minus_mu is None else dr.width(one_minus_mu),
                1 if pick is None else dr.width(pick[1]))
        m = self._largest(p)
        # The core's tolerance, and the flight's own rounding of t (a few ulps of t: beyond ~70 extents from the
        # ray's origin it outgrows the rest).
        t = self._event_t(t)
        tol = (SITE_COINCIDE * self.coincide + SITE_RELATIVE * m
               + FLIGHT_ROUNDING * self._tag_step(t, m, self._largest(d_in)) + dr.zeros(F, n))
        # The origin tag (module docs): a grain whose tag is p's within the search's shift of p (bounded from
        # the site's own t and p), or any grain within ``tol`` (a site whose tag search failed, or coincident
        # grains).
        tag = (origin_hash(p.x, p.y, p.z), tol, point_exponent(p.x, p.y, p.z)) if EXCLUSION == "origin" else None
        if tag is not None:
            tol = tol + self._shift_bound(t, p, d_in)
        evaluating = one_minus_mu is not None
        if evaluating:
            one_minus_mu = F(one_minus_mu)
            c_pick, u = dr.zeros(U, n), dr.zeros(F, n)
        elif pick is not None:
            one_minus_mu = dr.zeros(F, n)
            c_pick, u = U(pick[0]), F(pick[1])
        else:
            one_minus_mu = dr.zeros(F, n)
            c_pick, u = dr.zeros(U, n), dr.zeros(F, n)
        A = [dr.zeros(F, n) for _ in range(ch)]
        N = [dr.zeros(F, n) for _ in range(ch * self.E)]  # channel c's element k at c * E + k
        T = dr.zeros(F, n)
        W = dr.zeros(F, n)
        picked = dr.full(U, 0xFFFFFFFF, n)
        wave = self._channel_wave(waves, c_pick) if pick is not None else None
        step = self._accumulate if evaluating else self._reservoir if pick is not None else self._count
        arg = waves if evaluating else wave
        state = [A, N, T, W, u, picked]
        def visit(tau, b, member, st):
            return list(step(tau, b, member, one_minus_mu, arg, *st))

        if self.proc is not None:
            A, N, T, W, u, picked = self.proc.site_walk(p, d_in, tol, visit, state, active, tag)
        elif self.grid is not None:
            A, N, T, W, u, picked = self._stored_site_walk(p, d_in, tol, one_minus_mu, arg, step, state, active, tag)
        if self.field is not None:
            # No grain at p: a field event where p's cell has sigma_t > 0 (module docs, "Continuous size classes"):
            # the same steps over the cell's entries, tau_j replaced by their extinction shares s_i.
            A, N, T, W, u, picked = self.field.cell_walk(p, visit, [A, N, T, W, u, picked], mi.Bool(active) & (T == 0))
        return A, N, T, (picked, u)

    @dr.syntax
    def _stored_site_walk(self, p, d_in, tol, one_minus_mu, arg, step, state, active, tag=None):
        """``_site_sums``' walk of a stored grid: ``step`` at every grain of the cells within each size class's
        reach of ``p``, with its membership of the site (``DiscreteMedium::site_near``'s rule, R grown by the base
        tolerance: a far flight's rounding of t, across the ray too, may put a grazing site a hair outside; with
        ``tag`` = (p's ``origin_hash``, the base tolerance, its ``point_exponent``) a member also carries its tag there
        (``tags_agree``) within its R, or projects within the base tolerance)."""
        g_ = self.grid
        F, I, U = mi.Float, mi.Int32, mi.UInt32
        n = dr.width(tol)
        px, py, pz = F(p.x), F(p.y), F(p.z)
        dx, dy, dz = F(d_in.x), F(d_in.y), F(d_in.z)
        A, N, T, W, u, picked = state
        k = dr.select(mi.Bool(active), U(0), g_._n_classes)  # inactive lanes walk nothing
        while k < g_._n_classes:
            inv_cell = dr.gather(F, g_._inv_cell, k)
            soff = dr.gather(U, g_._class_start, k)
            frame = g_.frame(k)
            dims = [dr.gather(I, g_._dims, 3 * k + a) for a in range(3)]
            # The cells within the class's reach of p (a grain is stored in its centre's cell).
            reach = dr.gather(F, g_._reach, k)
            pq = (px, py, pz)
            at = [(pq[a] - dr.gather(F, g_._lo, 3 * k + a)) * inv_cell for a in range(3)]
            c0 = [dr.maximum(I(dr.floor(at[a] - reach)), 0) for a in range(3)]
            c1 = [dr.minimum(I(dr.floor(at[a] + reach)), dims[a] - 1) for a in range(3)]
            x0, x1 = c0[0], c1[0]
            ny = dr.maximum(c1[1] - c0[1] + 1, 1)
            rows = dr.select((x0 <= x1) & (c0[1] <= c1[1]) & (c0[2] <= c1[2]), ny * (c1[2] - c0[2] + 1), 0)
            r = dr.zeros(I, n)
            while r < rows:
                y = c0[1] + r % ny
                z = c0[2] + r // ny
                ok = r < rows
                row = soff + U((z * dims[1] + y) * dims[0])
                g = g_.start_of(row + U(x0), ok)
                g1 = dr.select(ok, g_.start_of(row + U(x1 + 1), ok), g)
                while g < g1:
                    centre, radius, code = g_.grain(g, frame, x0, y, z, g < g1)
                    vx, vy, vz = centre[0] - px, centre[1] - py, centre[2] - pz
                    along = vx * dx + vy * dy + vz * dz
                    qx, qy, qz = vx - along * dx, vy - along * dy, vz - along * dz
                    rim = radius + (tag[1] if tag is not None else tol)  # the flight's rounding across, too
                    member = (dr.abs(along) <= tol) & (qx * qx + qy * qy + qz * qz < rim * rim)
                    if dr.hint(tag is not None, mode="scalar"):
                        # The search kept the picked grain's site inside its ball: its shift is also within R.
                        shifted = (tags_agree(tag[0], grain_hash(g), radius, tag[2], g_.tag_thresholds)
                                   & (dr.abs(along) <= tag[1] + radius))
                        member &= shifted | (dr.abs(along) <= tag[1])
                    A, N, T, W, u, picked = step(g_.tau_of(code, member), g_.bin_of(code, member), member, one_minus_mu,
                                                 arg, A, N, T, W, u, picked)
                    g += 1
                r += 1
            k += 1
        return A, N, T, W, u, picked

    def _accumulate(self, tau, b, member, one_minus_mu, waves, A, N, T, W, u, picked):
        """``_site_sums``' step at a grain of optical depth ``tau`` and bin ``b`` (a member of the site or not)
        when evaluating at ``one_minus_mu``."""
        ch = self.channels
        a_new, n_new = [], []
        for c in range(ch):
            w = dr.select(member, tau * self._bin_albedo(b, waves[c], member) * self._scale, 0.0)
            a_new.append(A[c] + w)
            e = self._bin_elements(b, waves[c], one_minus_mu, member & (w > 0))
            n_new.extend(N[c * self.E + k] + w * e[k] for k in range(self.E))
        return a_new, n_new, T + dr.select(member, tau, 0.0), W, u, picked

    def _count(self, tau, b, member, one_minus_mu, wave, A, N, T, W, u, picked):
        """``_site_sums``' step at a grain of bin ``b`` when counting the site's grains (``T``) and keeping the
        first one's bin."""
        return A, N, T + dr.select(member, 1.0, 0.0), W, u, dr.select(member & (T == 0), b, picked)

    def _reservoir(self, tau, b, member, one_minus_mu, wave, A, N, T, W, u, picked):
        """``_site_sums``' step at a grain of optical depth ``tau`` and bin ``b`` when picking a grain's bin by
        tau_j a_jc in the picked channel (its bracket ``wave``): one pass of weighted reservoir sampling with one
        uniform, rescaled at each grain, so that ``u`` ends uniform whatever is picked (``T`` counts the
        members)."""
        w = dr.select(member, tau * self._bin_albedo(b, wave, member) * self._scale, 0.0)
        W = W + w
        share = dr.select(W > 0, w / dr.select(W > 0, W, 1.0), 0.0)
        take = (w > 0) & (u < share)
        u = dr.select(take, u / dr.select(share > 0, share, 1.0),
                      dr.select(w > 0, (u - share) / dr.select(share < 1, 1 - share, 1.0), u))
        u = dr.clip(u, 0.0, 0.99999994)
        return A, N, T + dr.select(member, 1.0, 0.0), W, u, dr.select(take, b, picked)

    def _site(self, p, d_in, waves, t, one_minus_mu=None, pick=None, active=True):
        """The site at ``p`` on the ray along ``d_in`` (module docs), its channels' wavelengths bracketed by
        ``waves`` (``_waves``), ``t`` along it (``mei.t``, ``_site_sums``). With ``one_minus_mu``: (elements per
        channel, ``elements[c][k]``, pdf, -); with ``pick`` = (channel, uniform): (-, members, (the picked grain's
        bin or 2^32 - 1, the uniform left)); at a field event the members are the cell's entries
        (``_site_sums``).

        Evaluating, a first walk only counts the site's grains and keeps the first (no table read per grain
        tested: a masked lane costs as much as an active one in a SIMD packet); a site of one grain, most,
        then reads its bin's tables once, and only the lanes of sites of several grains walk again, summing
        their mixture (``_mixture``)."""
        if one_minus_mu is None:
            with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):  # as the walk (drjit_walk's module docs)
                _, _, T, picked = self._site_sums(p, d_in, waves, None, pick, active, t)
            return None, T, picked
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            _, _, members, (first, _) = self._site_sums(p, d_in, waves, None, None, active, t)
        one = mi.Bool(active) & (members == 1)
        value, pdf = self._mixture(p, d_in, waves, one_minus_mu, active=mi.Bool(active) & (members > 1), t=t)
        value, pdf = self._one_grain(first, waves, one_minus_mu, one, value, pdf)
        return value, pdf, None

    def _one_grain(self, b, waves, one_minus_mu, one, elements, pdf):
        """(elements per channel, pdf) of a site of one grain of bin ``b`` at ``one_minus_mu`` where ``one``, else the
        given ones: its bin's tables times its albedo (the grain's optical depth cancels)."""
        ch = self.channels
        p1 = dr.zeros(mi.Float, dr.width(one_minus_mu))
        out = []
        for c in range(ch):
            a_c = self._bin_albedo(b, waves[c], one) * self._scale
            e = self._bin_elements(b, waves[c], one_minus_mu, one & (a_c > 0))
            out.append([dr.select(one, a_c * e[k], elements[c][k]) for k in range(self.E)])
            p1 += e[0]
        return out, dr.select(one, p1 / ch, pdf)

    def _mixture(self, p, d_in, waves, one_minus_mu, active, t):
        """(elements per channel, pdf) at ``one_minus_mu`` of the site's mixture, summed over its grains in one walk:
        per channel sum_j tau_j a_jc e_jc / sum_j tau_j (the site's albedo times the mixture), the pdf the mean over
        channels of the mixture's F11."""
        ch, E = self.channels, self.E
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True):
            A, N, T, _ = self._site_sums(p, d_in, waves, one_minus_mu, None, active, t)
        inv_t = dr.select(T > 0, 1 / dr.select(T > 0, T, 1.0), 0.0)
        elements = [[N[c * E + k] * inv_t for k in range(E)] for c in range(ch)]
        pdf = dr.zeros(mi.Float, dr.width(T))
        for c in range(ch):
            pdf += dr.select(A[c] > 0, N[c * E] / dr.select(A[c] > 0, A[c], 1.0), 0.0)
        return elements, pdf / ch
