"""Mitsuba medium ``discrete``: a cloud of individual particles (dust, snow, powder, bubbles) whose grains
are visible where they are few and large and which turns into an ordinary hazy medium where they are many
and small (Guo et al., Sec. 5). Rendered by Mitsuba's own ``volpath`` and ``volpathmis``.

===========================  =========  ======================================================================
Parameter                    Type       Meaning (default)
===========================  =========  ======================================================================
``filename``                 string     Particle file (.npz, .npy, .csv, .ply; see ``motes.load_particles``;
                                        a relative path is looked up in the scene file's folder), positions
                                        in the medium's local units. Without it particles are
                                        generated: without ``to_world`` they fill the shapes that hold the
                                        medium, their inside in world space (see "Filling the shapes that
                                        hold it"); with it, the local cube [-1, 1]^3 through it:
``count``                    integer    number of generated particles, spread over the holders' inside or
                                        the box (10000; at most 1e9 stored, 1e15 procedural); or, as
                                        ``homogeneous`` takes it:
``sigma_t``                  float,     the bulk extinction per scene unit the grains make (Mitsuba reads it
                             rgb or     as ``homogeneous`` does: an rgb in [0, 1] times ``scale``, or above
                             spectrum   1): the number of generated grains is sigma_t V / <C_ext>, V the
                                        holders' inside volume (without ``to_world``) or the medium's box
                                        (``to_world`` of the local cube, 8 |det| units^3), in m^3 through
                                        ``scale_m``, <C_ext> the grains' own grey extinction cross
                                        section (each optics bin's truncated Q_ext times pi r^2, the mean over
                                        the PSD; ``motes.discrete.mean_extinction_um2``). A coloured sigma_t:
                                        grains' extinction is grey, so the mean over the channels is taken and
                                        a warning says so (colour comes from ``albedo``). With ``distribution``
                                        gradient or noise it is the box's mean (without ``to_world``: the
                                        holders' box); with ``count`` or
                                        ``filename`` an error. Or a volume, as ``heterogeneous`` takes
                                        it (``gridvolume``, ``constvolume``): the grains' number density
                                        follows it (a grid interpolated trilinearly, as Mitsuba does;
                                        its channels' mean where coloured), in the volume's own box
                                        (its ``to_world``; no rotation): see "From a heterogeneous medium"
``scale``                    float      multiplies sigma_t (1; alone: sigma_t = 1 times it, as
                                        ``homogeneous``)
``distribution``             string     ``uniform``, ``gradient`` (concentration falling linearly along
                                        local +z) or ``noise`` (fBm noise, scale 0.5) (``uniform``).
                                        Generated in the core tile by tile (``seed`` fixes every grain
                                        whatever the thread count; ``rust/motes-core/src/space/cloud.rs``)
``radius_median``            float      log-normal PSD of the radii: median in um (20)
``radius_sigma_g``           float      log-normal geometric standard deviation, >= 1 (1.5)
``psd``                      string     any PSD as JSON, e.g. ``{"type": "uniform", "r_min_um": 5,
                                        "r_max_um": 50}``; replaces the two above
``material``                 string     ``ice`` or ``water`` (tabulated indices); or give ``eta``:
``eta``, ``eta_k``           float      particle refractive index n + i k (1.31, 0)
``eta_medium``               float      index of the host medium (1.0). eta equal to it with eta_k 0 is an
                                        error: grains of their host's index neither scatter nor absorb (an
                                        index near it gives a faint, mostly forward-scattering medium)
``species``                  string     JSON list of species for mixtures, each ``{"psd": {...}, "material":
                                        "ice"}`` or ``{"psd": ..., "eta": [n, k]}``, optional ``"share"`` (relative);
                                        replaces psd/material/eta. Files give each particle's species index
``scale_m``                  float      metres per scene unit (the units after ``to_world``), so that um radii
                                        and positions combine (1e-3)
``query_radius``             float      r_c of the query cylinder in scene units (0: the particles' own
                                        cross sections, widened where needed by ``tau_max``). Or Eq. 23:
``footprint_k``              float      k in (0, 2] (paper: 0.5-1), with ``fov`` (degrees), ``film_width``
                                        (pixels) and ``z_med`` (nearest depth of the medium, scene units)
``tau_max``                  float      cap on each particle's optical depth (1): a particle whose disk
                                        r_c + r_i would be more opaque gets a wider disk; each disk removes
                                        exactly its C_ext from a beam (see Notes)
``cells_per_particle``       float      grid resolution (0.125: about eight particles per cell); at most
                                        2e8 / count (a grid takes at most 2e8 cells), or with storage =
                                        procedural 2^22 over a brick's grains; the grid's cells count in the
                                        memory estimate (16 bytes each to build)
``continuous_count``         float      size classes with at least this many particles per query cylinder
                                        (over a mean free path or across the cloud) are rendered as a
                                        continuous medium: no pixel resolves their grains (16; inf: none)
``grain_depth``              integer    a path's rays walk grains one by one until its ``grain_depth``-th
                                        scattering event, and after it see their continuous equivalent
                                        where their pixel footprint holds ``continuous_count`` grains (the
                                        rule of rays from surfaces, below; a sparse cloud of large grains,
                                        each of whose shadows matters, is walked all along) (1: grains are
                                        seen where a path meets them first; ignored when
                                        ``continuous_count`` is inf, which keeps every ray exact); at most
                                        2^32 - 1
``surface_footprint``        boolean    the automatic level of detail: rays that start at no event (a
                                        camera's, a wall's shadow ray, a bounce off the floor) see the
                                        grains' continuous equivalent where the narrowest pixel footprint
                                        they can carry holds ``continuous_count`` grains (an effective count
                                        over the discrete size classes), camera rays also 2.5 grains per
                                        sample per pixel (their texture then stays below the render's
                                        noise): a cloud seen from afar is rendered as a continuous medium,
                                        the same cloud seen from nearby as grains. The cameras (perspective,
                                        thin lens, orthographic) and the render's spp are read from the
                                        scene at every load and ``mi.render``
                                        (``rust/motes-core/src/render/footprint.rs``; true; false: every
                                        ray from no event walks the grains)
``storage``                  string     ``compact``: each particle is a class (its optics bin and one of 1024
                                        radius levels per bin; radii move by at most half a level), stored
                                        once in its centre's grid cell at 6e-5 of a cell from 65536
                                        discrete grains up: 11-14 bytes per discrete grain, 4-5 per
                                        continuous one; ``full``: radii and
                                        positions as given, 60-75 bytes per discrete grain;
                                        ``procedural``: generated particles are never stored, each brick of
                                        the cloud generated from ``seed`` when a ray first needs it (``count``
                                        up to 1e15, a Poisson mean; memory follows what a render visits)
                                        (``compact``; see ``motes.DiscreteMedium``)
``cache_mb``                 float      ``storage = procedural``: megabytes of generated bricks kept between
                                        rays (the least recently used are dropped beyond it and generated
                                        again when needed) (a quarter of the memory available at load)
``size_bins``                integer    radius bins of the optics tables per species (16)
``method``                   string     ``auto``, ``mie``, ``goa`` or ``hybrid`` (``auto``)
``truncate_below``           float      forward-peak truncation angle in radians; default (or any negative
                                        value, so that a scene parameter can ask for it): the pixel
                                        footprint fov / film_width when ``fov`` and ``film_width`` are
                                        given, else 0.0313 (one bin of a 4096-value tabphase, as
                                        ``homogeneous_equivalent``); 0: none
``wavelengths``              string     tabulated wavelengths in um, comma-separated (spectral variants:
                                        8 from 0.38 to 0.78; RGB variants: 0.630, 0.532, 0.467); one
                                        outside 0.01-100 um is an error (nanometres, most likely)
``seed``                     integer    seed of generated positions and free flights (0)
``time``                     float      seconds since the cloud was at rest; generated grains move with (0):
``velocity``                 vector     uniform velocity, scene units per second ("0, 0, 0")
``turbulence``               float      amplitude A (scene units) of a smooth, seeded drift around the mean
                                        path whose displacement field is divergence-free (a uniform cloud
                                        stays uniform to O((A / L)^2); keep A well below L) (0: none)
``turbulence_scale``         float      spatial scale of the drift, scene units (a quarter of the cloud's
                                        largest extent); ``rust/motes-core/src/space/motion.rs``. Each grain
                                        keeps its radius and species; the medium's shape must hold the
                                        grains where they move to, or:
``wrap``                     boolean    grains that leave the cloud's box come back through the opposite
                                        face (periodic: a snowfall that never runs out) (false; stored only)
``albedo``                   float,     replaces every particle's albedo, in [0, 1] (tests, stylisation; a
                             rgb,       drop-in ``homogeneous`` scene's colour): a float for every channel, an
                             spectrum   rgb or spectrum per channel (RGB variants: R, G, B; spectral: its value
                             or volume  at each tabulated wavelength); a volume (``heterogeneous``'s): its mean
                                        per channel over its box, with one line saying so (a grain's albedo
                                        does not vary in space) (the physical albedo; ``homogeneous``'s
                                        default 0.75 is not taken)
``phase_model``              string     ``tabulated``: the grains' own phase functions (Eq. 17 per size bin);
                                        ``hg``: Henyey-Greenstein with the same g per bin and channel, the
                                        model graphics often uses instead (paper Fig. 13) (``tabulated``)
``to_world``                 transform  places the particle positions in the scene (radii stay physical):
                                        the local cube [-1, 1]^3 of generated ones, or a file's. Without it
                                        (and without ``filename``) the grains fill the shapes that hold the
                                        medium, as ``homogeneous`` does; give it to fill a box instead
``sample_emitters``          boolean    next-event estimation at scattering events (true)
``kernel``                   string     ``native``: the C++/Rust render path where it is built (below, "Render
                                        paths"); ``drjit``: Dr.Jit-typed code traced into Mitsuba's kernels,
                                        no Rust call at render time (every ``llvm_ad_*`` and ``cuda_ad_*``;
                                        continuous size classes render as their field, stored or procedural;
                                        every ray walks the discrete classes' grains: ``grain_depth`` and
                                        ``surface_footprint`` change nothing; scalar variants are an error;
                                        ``cells_per_particle`` defaults to 2 there;
                                        ``motes/plugins/drjit_medium.py``) (``native``; ``drjit``, the only
                                        one, in ``cuda_ad_*``)
``has_spectral_extinction``  boolean    as ``homogeneous`` takes it: false is what this medium does (grey free
                                        flights); true is ignored, with one warning (false)
``<phase>`` child            phase      the grains' phase function: ``particle``, their own (the default, also
                                        without a child); ``isotropic``, ``hg`` (its ``g``) or ``tabphase``
                                        (its ``values``): that function for every bin and channel instead
                                        (extinction and albedo stay the grains'); any other type is an error
===========================  =========  ======================================================================

Scene parameters (``mi.traverse(scene)``): ``albedo_scale``, a factor on every particle's albedo (1 as
loaded; a one-element tensor, checked to keep albedos within [0, 1]), editable between renders; and the
phase function. Everything else is fixed at load.

Defaults are part of the physics. With the paper's normalisation (tau_i = C_ext / (pi R_i^2)) a disk
R_i = r_c + r_i with r_c = 0 has tau_i ~ 2, lets rays through it 13 % of the time and removes only 43 %
of C_ext: 57 % of the side scattering was lost against explicit spheres. Each disk's optical depth is
therefore -ln(1 - C_ext / (pi R_i^2)), which removes exactly C_ext from a beam whatever r_c, and disks
are widened until tau_i <= ``tau_max``. A ``query_radius`` that widening overrides for more than 0.1 % of
the particles raises a warning.
Forward-peak truncation is on by default: a diffraction lobe a few mrad wide cannot be found by a delta
light (spot, point) except as fireflies, so without it a spot-lit floor under 80 um grains renders
37 % +- 5 % dark at 64 spp (``scripts/bench/bench_spotlit.py``; BENCHMARKS.md, "Rendering accuracy").
Grains nobody can see are not walked one by one: a size class whose particles a pixel's query cylinder
holds many of (``continuous_count``) has each tau_i tiny and no resolvable grain, so it is sampled as a
continuous medium with the same extinction per cell and the cell's phase mixture, combined exactly
with the discrete classes (the nearer of the two sampled interactions). What it drops is the grain
texture of relative size 1/sqrt(N) (BENCHMARKS.md, "Rendering accuracy").

``storage = procedural`` stores no particle (``rust/motes-core/src/render/procedural/``): the continuous
classes are the density field's expected extinction, and the grains that stay discrete are generated
brick by brick, from ``seed`` and the brick's tiles, when a ray first reaches a brick; the same grains in
every render and pass. Loading costs nothing whatever ``count``; a render costs the bricks it visits.
Where few of the cloud's discrete grains are in view (occluded, outside the frame, behind an optically
thick front) or most of its grains are continuous, that is little; where every discrete grain of the
cloud is in view, a pass generates what a stored build would, and only a cache that holds all their
bricks (``cache_mb``; about 40 bytes per visible grain) keeps later passes from generating them again
(BENCHMARKS.md, "Memory and scale"). ``count`` is the mean of a Poisson count, not an exact one.

The phase function is the ``<phase>`` child: ``particle`` (or none) renders the grains' own; ``isotropic``,
``hg`` and ``tabphase`` give every grain that function (the plugin puts a ``particle`` phase function in their
place, which renders it: the render path stays the same). Invalid values and unknown or misspelt
parameters fail loading with one ``ValueError`` (through Mitsuba's loaders a RuntimeError, without the
plugin's Python traceback) that lists each: the parameter, its value and what it takes.

From a homogeneous medium
-------------------------
A scene's ``homogeneous`` medium turns ``discrete`` by changing its type and adding a grain size
(``radius_median``; ``scale_m`` where a scene unit is not a millimetre): without ``to_world`` the grains fill the
shapes that hold it, as ``homogeneous`` does (below). ``sigma_t``, ``scale``, ``albedo`` (float or rgb),
``sample_emitters``, ``has_spectral_extinction`` and the phase child (``isotropic``, ``hg``, ``tabphase``) keep their meaning; the grains then make the same
mean transmittance exp(-sigma_t L) (``tests/test_dropin.py``; ``scripts/bench/bench_dropin.py`` compares three
such scenes with their homogeneous originals). What differs is the grains themselves: visible where they
are few and large, and a grey extinction. Too many grains for a stored cloud (sigma_t V / <C_ext> above
1e9) is an error that says so: use ``storage = procedural``, larger grains or a smaller ``scale_m``.

From a heterogeneous medium
---------------------------
A ``heterogeneous`` medium turns ``discrete`` the same way: its ``sigma_t`` volume (a ``gridvolume`` from a .vol
file, or a ``constvolume``) times ``scale`` becomes the grains' number density, n(x) = sigma_t(x) / <C_ext>: the
count is the grid's mean (exact for its trilinear interpolant: the mean of its values) times its box's volume over
<C_ext>, and the grains are generated after the grid interpolated as Mitsuba interpolates it (trilinear between
cell centres, clamped at the faces; ``motes_core::space::cloud``, ``Density::Grid``), with ``storage`` compact,
full or procedural alike. The grid's box is the volume's own (its ``to_world``, which may translate and scale it;
a rotated or sheared grid is an error), so the medium takes no ``to_world`` and no ``distribution`` then. A
coloured grid's density is its channels' mean (one line says so). An ``albedo`` volume gives its mean.

Filling the shapes that hold it
-------------------------------
Without ``to_world`` and ``filename`` the generated grains fill the shapes whose interior the medium is, all of them
(a medium two shapes share fills both), in world space: uniform over their inside (their union), none outside,
``count`` of them or sigma_t V / <C_ext> with V the inside volume (exact: each mesh's by the divergence theorem, a
sphere's or cylinder's from its ``to_world``, summed where the shapes' boxes do not overlap; else from 2^20 seeded
samples of the inside test, about 0.1 %). Holders: closed triangle meshes (``obj``, ``ply``, ``cube``...: their
world-space triangles; every edge must belong to an even number of triangles, or loading fails naming the mesh),
``sphere`` and ``cylinder`` (solid, by their ``to_world``); any other shape (``rectangle``, ``disk``, instances) fails
loading naming it: give ``to_world``. The inside test and the sampling are the core's
(``rust/motes-core/src/space/inside.rs``: ray parity along +x over a 2D grid of the triangles, with the
rasteriser's fill rule at edges and vertices; candidates uniform in the shapes' boxes from ``seed``, kept in the
order of their index where the first shape holding them is the one whose box drew them: the same grains whatever
the thread count). Radii and species are drawn as for a generated cloud. The continuous equivalent's cells that the
shapes' surface cuts take their grains' extinction over their inside part only (``ContinuousField::confined``):
without it a sphere of 20 um grains at 1 mm per unit rendered 3-7 % brighter than ``homogeneous``
(``tests/test_dropin.py``).

Mitsuba builds a medium before the shapes that hold it, so such a medium is built once its scene has loaded
(``_scene.PendingFill``): the loaders (``scene_checks.wrap_loaders``) and ``mi.render`` (``cameras.attach``) hand it
its holders first; until then its native plugins let every ray through, and its ``str()`` in scalar variants stays
``DiscreteMedium[fills the shapes that hold it]``. A medium that no shape holds as its interior (loaded alone, only
an exterior or a camera's medium) keeps the local cube [-1, 1]^3, with a warning. Three cases need a box and take
the holders' bounding box as their ``to_world`` (the grains fill the box; those outside the shapes are never met):
``storage = procedural``, ``distribution`` gradient or noise, and ``wrap``. Moving grains (``velocity``,
``turbulence``) start from the filled positions. With ``to_world`` or ``filename`` nothing changes: the grains and
images are those of earlier versions, bit for bit.

How it maps onto Mitsuba's delta tracking
-----------------------------------------
Along a ray the discrete optical depth is a sum of per-particle steps, so the core samples the first
interaction *exactly* (``rust/motes-core/src/render/discrete/``). ``intersect_aabb`` returns that site as
``mint`` (nothing lies before it); ``get_majorant`` returns a huge constant ``MAJORANT``, so Mitsuba's
tentative distance lands on the site; ``get_scattering_coefficients`` returns ``sigma_t = MAJORANT`` and
``sigma_n = 0`` there, so every tentative collision is real. The result: no null collisions at all, and
sigma_t <= majorant everywhere (zero away from sites). A ray that leaves without interacting gets
``hit = False``. ``m_has_spectral_extinction`` is false and the free flight is grey per particle (the
mean of C_ext over the wavelengths); albedo and phase function are per channel. Events are remembered by
their exact position so that the scattered ray and its shadow rays skip the particle that scattered
them (every event is remembered: a perspective camera's rays have a finite t_max too, so t_max cannot
tell scattered rays from shadow rays; the native path remembers a site once the path's next call starts
there, so a shadow ray's site is never remembered). Events also carry the path's colour throughput, so that the
phase function picks the channel it samples in proportion to it and colour weights stay bounded over
hundreds of bounces. Random numbers for the free flights come from the core (counter-based, reproducible).

Polarisation
------------
In the polarised variants (``scalar_spectral_polarized``, ``llvm_ad_spectral_polarized``,
``llvm_ad_mono_polarized``) the grains scatter with their Mueller matrices: each bin keeps its ensemble's
F12/F11, F33/F11 and F34/F11 (Bohren & Huffman) beside its phase table, a site mixes its grains' elements
as it mixes their phase functions, and the phase function returns the matrix rotated from the scattering
plane's Stokes frames into Mitsuba's (``motes/native/motes_native.cpp``, "Polarised variants"). Sampling
draws from F11 as in the other variants; free flights are unpolarised. A user's ``<phase>`` (hg, tabphase,
isotropic) and ``phase_model = "hg"`` depolarise, as Mitsuba's own phase functions do. The continuous
equivalent carries the same matrices (its events mix the bins' tables), and
``motes.homogeneous_equivalent(..., polarized=True)`` gives a ``homogeneous`` medium with
``motes_tabphase_polarized``, which does too. Mitsuba's ``stokes`` integrator around ``volpath`` renders
the Stokes components.

Render paths
------------
In ``llvm_ad_rgb``, ``llvm_ad_spectral``, ``scalar_rgb``, ``scalar_spectral`` and the three polarised
variants above this plugin parses and
validates its parameters and builds the particles and optics, then hands every call to the native C++
medium and phase function (``motes/native/motes_native.cpp``), which run inside Mitsuba's default symbolic
kernels: one call into Rust per SIMD packet, events kept per thread, free flights seeded by a hash of the
ray (a render is a function of scene, seed and spp). There ``get_scattering_coefficients`` returns
``sigma_s = sigma_t`` without a call (every site scatters) and the phase function's values and weights
carry the site's albedo instead: Mitsuba's ``volpath`` and ``volpathmis`` multiply sigma_s / sigma_t and
the phase function's value into a path alike, so the image is the same; only ``mei.sigma_s`` read by a
custom integrator shows albedo 1 (the event is remembered when the path's next call starts at it, so the
renderer needs no call to place it). In the scalar variants the scene's medium is the
native medium itself (the plugin's factory returns it, so no call per ray goes through Python); it still
answers ``.data``, ``.stats``, ``str()`` and ``mi.traverse`` as below. In other variants, without a C++ compiler, with
``MOTES_NATIVE=0``, or when Dr.Jit is switched to evaluated mode, the calls go through numpy batches
instead (the evaluated-mode path below).

Under ``volpath`` and ``volpathmis`` (the integrator given to ``mi.render``, or the scene's) two things are skipped,
exactly (the images are the same; ``motes/plugins/enclosure.py``): a ray with a site is traced through the scene only
up to it (Mitsuba's ``is_homogeneous`` flag, set for those two integrators: this medium has no null collisions), and
next-event estimation's phase evaluation towards a light whose shadow ray ended at a site inside the convex shape
(a ``cube``, a convex mesh, a ``sphere``) that holds the medium answers zero without computing it (the light it
multiplies is zero). ``Integrator.render`` called directly skips neither unless
``motes.plugins.cameras.attach(scene, integrator=...)`` names that integrator first.
"""

from __future__ import annotations

import difflib
import json
import os
import time
import warnings
from types import SimpleNamespace

import drjit as dr
import mitsuba as mi
import numpy as np

from ..discrete import PHASE_TYPES, DiscreteMedium, box_of, log, mean_extinction_um2
from ..ensemble import DEFAULT_TRUNCATE_RAD, RGB_WAVELENGTHS_UM, SPECTRAL_WAVELENGTHS_UM, Material, Species, pixel_footprint_rad
from ..discrete import (DEFAULT_CELLS_PER_PARTICLE, DEFAULT_CONTINUOUS_COUNT, DEFAULT_GRAIN_DEPTH,
                        DEFAULT_STORAGE, DEFAULT_TAU_MAX, MAX_GRAIN_DEPTH, MAX_PROCEDURAL_COUNT, PHASE_MODELS,
                        STORAGES, implausible_wavelengths, species_shares)
from ..particle_io import ParticleFileError, load_particles
from ..particles import query_radius_from_camera
from .. import _memory, _motes, native
from .. import psd as psd_mod
from ._bridge import bind_to_variant, symbolic_mode, channel_wavelengths, is_jit, mask, require_evaluated_mode, spectrum, vec3
from . import cameras, particle_phase
from .drjit_medium import DRJIT_CELLS_PER_PARTICLE, KERNELS, DrJitKernel, default_kernel, kernel_problem
from ._scene import PendingFill, native_data, pending_of

#: What ``storage`` takes: a stored medium's two, or particles generated on demand and never stored.
PLUGIN_STORAGES = STORAGES + ("procedural",)

#: Every parameter of the table (module docs), for the "did you mean" of an unknown one.
PARAMETERS = ("filename", "count", "distribution", "radius_median", "radius_sigma_g", "psd", "material", "eta", "eta_k",
              "eta_medium", "species", "scale_m", "query_radius", "footprint_k", "fov", "film_width", "z_med", "tau_max",
              "cells_per_particle", "continuous_count", "grain_depth", "surface_footprint", "storage", "cache_mb",
              "size_bins", "method", "truncate_below", "wavelengths", "seed", "time", "velocity", "turbulence",
              "turbulence_scale", "wrap", "sigma_t", "scale", "albedo", "has_spectral_extinction", "phase_model",
              "to_world", "sample_emitters", "kernel")

#: sigma_t returned at a site; the tentative distance mint + E / MAJORANT rounds to the site itself.
MAJORANT = 1e20


class DiscreteMediumPlugin:
    """Methods of the plugin; ``plugin_class()`` binds them to the current variant's ``mi.Medium``."""

    #: The particles and optics (``motes.DiscreteMedium``), set by the constructor, or for a medium that fills its
    #: holders once its scene has loaded (``_motes_pending``, a ``_scene.PendingFill``, until then).
    _data: DiscreteMedium | None = None
    _motes_pending: PendingFill | None = None
    #: ``kernel = "drjit"``: the Dr.Jit-typed calls (``drjit_medium.DrJitKernel``), else None.
    _drjit: DrJitKernel | None = None

    @property
    def data(self) -> DiscreteMedium:
        """The particles and optics (``motes.DiscreteMedium``). A medium that fills its holders and that no loaded
        scene handed them (used alone) is made now in the local cube [-1, 1]^3, with a warning."""
        if self._data is None and self._motes_pending is not None:
            self._data = self._motes_pending.result()
        return self._data

    def __init__(self, props: mi.Properties):
        # The <phase> child: a particle phase function takes the place of any other (its function becomes
        # the grains', below), so that the render path is the same whatever the scene gave.
        user_phase = _take_phase_child(props)
        mi.Medium.__init__(self, props)
        self.m_is_homogeneous = False
        self.m_has_spectral_extinction = False
        p, bad = _read_parameters(props, user_phase)
        species = _collected(bad, _species, p, props)
        _raise_if_bad(bad)
        if p.spectral_extinction:
            warnings.warn("discrete medium: has_spectral_extinction = true is ignored: the grains' free flights are "
                          "grey (their albedo and phase function are per channel)", stacklevel=3)
        truncate = p.truncate
        if truncate is None:
            truncate = (pixel_footprint_rad(p.fov, p.film_width) if p.fov is not None and p.film_width is not None
                        else DEFAULT_TRUNCATE_RAD)
        lam = p.lam
        common = dict(scale_m=p.scale_m, size_bins=p.size_bins, eta_medium=p.eta_medium, method=p.method,
                      truncate_below_rad=truncate if truncate > 0 else None, cells_per_particle=p.cells, seed=p.seed,
                      albedo=p.albedo, tau_max=p.tau_max, continuous_count=p.continuous, grain_depth=p.grain_depth,
                      phase_model=p.phase_model, surface_footprint=p.surface_footprint, phase=p.phase,
                      polarized=bool(mi.is_polarized))
        cameras.note_medium()  # the loaders and mi.render set the scene's cameras on it (cameras.attach)
        phase = self.phase_function()
        if not getattr(phase, "is_motes_particle_phase", False):
            raise ValueError('discrete medium: its phase function must be <phase type="particle"/> '
                             "(the medium supplies the particles it scatters from)")
        self._native = self._native_phase = None
        build = _Build(p, species, lam, truncate, common, props.id() or "")
        if p.kernel == "drjit":  # no native objects: Dr.Jit-typed calls over the data, made now or once filled
            if p.filename is None and not p.to_world_given:
                source = self._motes_pending = PendingFill(build.filled)
            else:
                source = self._data = build.built(props)
            self._drjit = DrJitKernel(source, p.seed, MAJORANT)
            if self._data is not None:
                self._drjit.ready()  # its errors at load (a filled medium's: at its first call)
            phase.attach(source, None, self._drjit)
        elif p.filename is None and not p.to_world_given:
            # Its grains fill the shapes that hold it, which Mitsuba makes after it: built once its scene has loaded
            # (module docs, "Filling the shapes that hold it"). No Mitsuba object is kept (the native handles own it).
            pending = self._motes_pending = PendingFill(build.filled)
            if native_in_use():
                pending.handles = [_motes.native_pending_handle(pending) for _ in range(2)]
                self._native, self._native_phase = _native_objects(pending.handles, lam, bool(self.m_sample_emitters),
                                                                   self.to_string(), _polarizing(p))
            phase.attach(pending, self._native_phase)
        else:
            data = self._data = build.built(props)
            if native_in_use():
                handles = [data.core.native_handle(data) for _ in range(2)]
                self._native, self._native_phase = _native_objects(handles, lam, bool(self.m_sample_emitters),
                                                                   self.to_string(), _polarizing(p))
            phase.attach(data, self._native_phase)
        self._stats = dict(_NO_EVALUATED_CALLS)
        # Editable through mi.traverse (a one-element tensor: Mitsuba updates it in place).
        self._albedo_scale = mi.TensorXf(np.ones(1, dtype=np.float32))

    # -- Mitsuba interface -------------------------------------------------------------------------
    # Each method hands the whole call to the native plugin when there is one (traced once into
    # Mitsuba's symbolic kernel in LLVM variants), else goes through numpy batches (evaluated mode).
    def intersect_aabb(self, ray):
        if self._drjit is not None:
            return self._drjit.intersect_aabb(ray)
        if self._native is not None and symbolic_mode():
            return self._native.intersect_aabb(ray)
        require_evaluated_mode()
        o, d = vec3(ray.o), vec3(ray.d)
        n = o.shape[0]
        t_max = np.ascontiguousarray(np.broadcast_to(np.atleast_1d(np.asarray(ray.maxt, dtype=np.float64)), (n,)))
        # Every event is remembered (module docs): t_max cannot tell scattered from shadow rays.
        t, _ = self.data.core.sample_sites(o.ravel(), d.ravel(), t_max, np.ones(n, dtype=bool))
        hit = np.isfinite(t)
        self._stats["intersect_calls"] += 1
        self._stats["rays"] += n
        mint = np.where(hit, t, np.inf).astype(np.float32)
        maxt = np.where(hit, np.inf, -np.inf).astype(np.float32)
        if is_jit():
            return mi.Bool(hit), mi.Float(mint), mi.Float(maxt)
        return bool(hit[0]), float(mint[0]), float(maxt[0])

    def get_majorant(self, mei, active=True):
        if self._drjit is not None:
            return self._drjit.get_majorant(mei, active)
        if self._native is not None and symbolic_mode():
            return self._native.get_majorant(mei, active)
        # MAJORANT where intersect_aabb found a site, 0 elsewhere: integrators that weight by
        # exp(-t * majorant) over the whole segment (prbvolpath) then give escaping rays weight 1.
        n = max(dr.width(mei.wi), np.size(np.asarray(active)))
        return spectrum(np.where(mask(active, n), MAJORANT, 0.0)[:, None], n)

    def get_scattering_coefficients(self, mei, active=True):
        if self._drjit is not None:
            return self._drjit.get_scattering_coefficients(mei, active)
        if self._native is not None and symbolic_mode():
            return self._native.get_scattering_coefficients(mei, active)
        p = vec3(mei.p)
        n = p.shape[0]
        act = mask(active, n)
        lam, ch = channel_wavelengths(self.data, mei, n)
        albedo = self.data.core.commit_events(p.ravel(), act, lam, ch).reshape(n, ch)
        self._stats["events"] += int(act.sum())
        sigma_t = np.where(act, MAJORANT, 0.0)[:, None]
        sigma_n = np.zeros((n, 1))  # every tentative collision is real (module docs)
        self._stats["nulls"] += int((act & (sigma_n[:, 0] > 0)).sum())
        return (spectrum(albedo * sigma_t, n), spectrum(sigma_n, n), spectrum(sigma_t, n))

    # -- Scene parameters (mi.traverse) -------------------------------------------------------------
    def traverse(self, callback):
        """``albedo_scale``: a factor on every particle's albedo (1 as built), editable between renders
        through ``mi.traverse(scene)`` (e.g. ``params["<shape>.interior_medium.albedo_scale"] = 0.5``,
        then ``params.update()``); and the phase function. The particles and their optics are fixed at
        load: edit the XML for those."""
        callback.put("albedo_scale", self._albedo_scale, mi.ParamFlags.NonDifferentiable)
        callback.put("phase_function", self.phase_function(), mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys=None):
        if keys is None or "albedo_scale" in keys:
            try:
                self.data.core.set_albedo_scale(float(np.asarray(self._albedo_scale).ravel()[0]))
                if self._drjit is not None:
                    self._drjit.set_albedo_scale(self.data.core.albedo_scale)
            except ValueError:
                # The parameter goes back to the value in use, so that what mi.traverse shows is true.
                self._albedo_scale = mi.TensorXf(np.full(1, self.data.core.albedo_scale, dtype=np.float32))
                raise

    @property
    def stats(self) -> dict:
        """Counters of the render path so far: rays and events (both paths), batched intersect calls
        and null collisions (the evaluated-mode path)."""
        return _stats(self.data.core, self._stats)

    @property
    def device_bytes(self) -> dict:
        """``kernel = "drjit"``: bytes of the arrays it uploaded (``DrJitKernel.device_bytes``: grains, tables,
        total, per grain); empty on the native path or before the first render."""
        return {} if self._drjit is None else self._drjit.device_bytes()

    def to_string(self):
        d = self._data if self._motes_pending is None else self._motes_pending.data
        if d is None:
            return "DiscreteMedium[fills the shapes that hold it]"
        return d.summary() + ("" if self._drjit is None else "\n" + self._drjit.summary())


class _Build:
    """What the constructor read, and the two ways to build the medium's data from it: ``built``, now (a
    ``to_world`` or a particle file places the grains), or ``filled``, from the shapes that hold it once its scene
    has loaded (``_scene.PendingFill``; module docs, "Filling the shapes that hold it"). Holds no Mitsuba object
    beyond the parameters' values (a native handle owns it)."""

    def __init__(self, p: SimpleNamespace, species: list, lam: np.ndarray, truncate: float, common: dict, name: str):
        self.p, self.species, self.lam, self.truncate, self.common, self.name = p, species, lam, truncate, common, name

    def built(self, props=None) -> DiscreteMedium:
        """The data with the grains in ``to_world``'s box (or a file's): the constructor's, as it always was."""
        p, species, lam, common = self.p, self.species, self.lam, self.common
        if p.sigma_t is not None:
            p.count = _count_of_extinction(p, species, lam, self.truncate if self.truncate > 0 else None)
        if p.storage == "procedural":
            return _procedural(p, species, lam, common)
        pos, radii, sidx = _particles(p, props, species)
        query_radius, user_radius = _query_radius(p, pos)
        return DiscreteMedium(pos, radii, sidx, species, lam, query_radius=query_radius, warn_widened=user_radius,
                              storage=p.storage, density=_density_drawn_from(p), **common)

    def filled(self, shapes: list) -> DiscreteMedium:
        """The data with the grains filling ``shapes`` (their union, in world space); none: the local cube [-1, 1]^3
        with a warning."""
        p, species, lam, common = self.p, self.species, self.lam, self.common
        name = repr(self.name) if self.name else "(unnamed)"
        if not shapes:
            warnings.warn(f"discrete medium {name}: no shape holds it and it has no to_world nor filename: its grains "
                          "fill the local cube [-1, 1]^3 (make it a shape's interior to fill that shape, or give "
                          "to_world)", RuntimeWarning, stacklevel=2)
            data = self.built()
            data.fills_holders = False
            return data
        t = time.perf_counter()
        holders = _holders_of(shapes, name)
        (lo, hi), names = holders.bounds, ", ".join(repr(s.id() or "(unnamed)") for s in shapes)
        box = np.eye(4)
        box[:3, :3] *= (np.asarray(hi) - np.asarray(lo)) / 2
        box[:3, 3] = (np.asarray(hi) + np.asarray(lo)) / 2
        if p.storage == "procedural" or p.distribution != "uniform" or p.wrap:
            # These take a box: the holders' (grains outside the shapes are never met).
            p.to_world = mi.ScalarTransform4f(box.tolist())
            log.info("fill: %s's box %s..%s (storage %s, distribution %s, wrap %s)", names, lo, hi, p.storage,
                     p.distribution, p.wrap)
            data = self.built()
        else:
            volume, exact = holders.volume(p.seed)
            if p.sigma_t is not None:
                p.count = _count_of_extinction(p, species, lam, self.truncate if self.truncate > 0 else None, volume,
                                               f"the inside of {names}")
            pos = holders.fill(p.count, p.seed).reshape(-1, 3)
            shares = species_shares(species)
            # Radii and species as a generated cloud draws them (its positions are not used).
            _, radii, sidx = _motes.generate_cloud(p.count, [-1.0] * 3, [1.0] * 3, "uniform", [], p.seed,
                                                   [sp.psd._core for sp in species], shares, p.seed,
                                                   np.eye(4)[:3].tolist())
            if p.moving and p.time != 0:
                pos = _motes.move_grains(pos.ravel(), p.velocity.tolist(), p.turbulence, _turbulence_scale(p, box),
                                         p.seed, p.time, None).reshape(-1, 3)
            log.info("fill: %d grains inside %s (%.4g units^3%s) in %.1f s", p.count, names, volume,
                     "" if exact else ", Monte Carlo", time.perf_counter() - t)
            query_radius, user_radius = _query_radius(p, pos)
            data = DiscreteMedium(pos, radii, sidx, species, lam, query_radius=query_radius,
                                  warn_widened=user_radius, storage=p.storage, holders=holders, **common)
        data.fills_holders = True
        return data


def _holders_of(shapes: list, name: str):
    """The inside of ``shapes`` for the core (``_motes.Holders``): closed meshes (world-space vertices), Mitsuba's
    ``sphere`` and ``cylinder`` (solid) by their ``to_world``; any other shape, or a mesh that is not closed, is a
    ValueError naming it."""
    meshes, balls, cylinders = [], [], []
    for shape in shapes:
        sid, kind = repr(shape.id() or "(unnamed)"), shape.class_name()
        params = mi.traverse(shape)
        if shape.is_mesh() and "vertex_positions" in params and "faces" in params:
            v = np.asarray(params["vertex_positions"], dtype=np.float64).ravel()
            f = np.asarray(params["faces"], dtype=np.uint32).ravel()
            open_edges = _motes.mesh_open_edges(v, f)
            if open_edges:
                raise ValueError(f"discrete medium {name}: the mesh {sid} that holds it is not closed ({open_edges} "
                                 "edges belong to an odd number of its triangles), so it has no inside for the grains "
                                 "to fill: close the mesh, or give the medium a to_world (the box its grains fill)")
            meshes.append((v, f))
        elif kind in ("Sphere", "Cylinder") and "to_world" in params:
            m = np.asarray(params["to_world"].matrix, dtype=np.float64).reshape(4, 4, -1)[..., 0]
            (balls if kind == "Sphere" else cylinders).append(m[:3].tolist())
        else:
            raise ValueError(f"discrete medium {name}: its grains fill the shapes that hold it, and the shape {sid} "
                             f"({kind}) has no inside it can fill (closed meshes, sphere and cylinder can): give the "
                             "medium a to_world (the box its grains fill)")
    return _motes.Holders(meshes, balls, cylinders)


# -- The constructor's steps -----------------------------------------------------------------------
#: Mitsuba's phase function plugins by class name (``<phase type=...>``), and those whose function a
#: discrete medium's grains take (``particle``, the grains' own, is the default).
MITSUBA_PHASES = {"IsotropicPhaseFunction": "isotropic", "HGPhaseFunction": "hg", "TabulatedPhaseFunction": "tabphase",
                  "RayleighPhaseFunction": "rayleigh", "SGGXPhaseFunction": "sggx", "BlendPhaseFunction": "blendphase"}
PHASE_CHILDREN = ("particle",) + PHASE_TYPES


def _take_phase_child(props):
    """The medium's ``<phase>`` child as the grains' phase function (``motes.discrete.phase_table``'s dict;
    None: ``particle`` or none given, the grains' own) or the problem with it (a string), replaced in ``props``
    by a ``particle`` phase function, which renders whatever the tables hold. Two children: left to Mitsuba."""
    children = [(k, o) for k, o in props.objects() if isinstance(o, mi.PhaseFunction)]
    if len(children) > 1 or (children and getattr(children[0][1], "is_motes_particle_phase", False)):
        return None
    spec = None
    if children:
        key, child = children[0]
        name = MITSUBA_PHASES.get(child.class_name(), child.class_name())
        params = mi.traverse(child)
        if name == "isotropic":
            spec = {"type": "isotropic"}
        elif name == "hg":
            spec = {"type": "hg", "g": float(np.asarray(params["g"]).ravel()[0])}
        elif name == "tabphase":
            spec = {"type": "tabphase", "values": np.asarray(params["values"], dtype=np.float64).ravel().tolist()}
        else:
            spec = (f'phase function <phase type="{name}">: a discrete medium takes ' +
                    ", ".join(PHASE_CHILDREN) + " (particle, the grains' own, is the default)")
    else:
        key = "phase"
    props[key] = particle_phase.plugin_class()(mi.Properties("particle"))
    return spec


def _collected(bad: list, fn, *args):
    """``fn(*args)``, or None with its ValueError added to ``bad``."""
    try:
        return fn(*args)
    except ValueError as e:
        bad.append(str(e))
        return None


def _raise_if_bad(bad: list) -> None:
    """One ValueError for every problem found (one problem: its own message, as it always read)."""
    if len(bad) == 1:
        raise ValueError(bad[0])
    if bad:
        items = [b.removeprefix("discrete medium: ") for b in bad]
        raise ValueError(f"discrete medium: {len(bad)} problems with its parameters:\n  " + ";\n  ".join(items))


def _read_parameters(props, user_phase=None) -> tuple[SimpleNamespace, list]:
    """Every parameter of the table (module docs), read in one place so that Mitsuba counts each as used:
    (the parameters, a message for each invalid or unknown one). ``user_phase``: ``_take_phase_child``'s."""
    bad: list[str] = []
    get = lambda *args: _get(props, *args, bad=bad)  # noqa: E731
    p = SimpleNamespace()
    _read_grains(props, p, bad, get)
    _read_rendering(props, p, bad, get)
    _read_motion(props, p, bad, get)
    p.phase_model = get("phase_model", "tabulated", str, lambda v: v in PHASE_MODELS,
                        "one of " + ", ".join(PHASE_MODELS))
    p.to_world_given = "to_world" in props
    p.to_world = props.get("to_world") if p.to_world_given else mi.ScalarTransform4f()
    _read_homogeneous_keys(props, p, bad, get)
    # The phase child (_take_phase_child).
    p.phase = user_phase if isinstance(user_phase, dict) else None
    if isinstance(user_phase, str):
        bad.append(f"discrete medium: {user_phase}")
    if p.phase is not None and p.phase_model != "tabulated":
        bad.append(f"discrete medium: phase_model = {p.phase_model} and <phase type=\"{p.phase['type']}\"> both set "
                   "the grains' phase function: keep one")
    if p.material is not None and ("eta" in props or "eta_k" in props):
        bad.append("discrete medium: give material or eta/eta_k, not both (eta would be ignored)")
    if bad and p.to_world is not None:
        _collected(bad, _checked_to_world, p)
    unknown = [k for k in props.unqueried() if not k.startswith("_arg_")]
    for k in unknown:
        close = difflib.get_close_matches(k, PARAMETERS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        bad.append(f"discrete medium: unknown parameter '{k}' = {_shown(props, k)}{hint}; the parameters are "
                   "listed in motes.plugins.discrete_medium's docs")
    return p, bad


def _read_grains(props, p: SimpleNamespace, bad: list, get) -> None:
    """The grains: where they come from (a file, or generated: count, distribution), their sizes, index and units (``_read_parameters``)."""
    pos_f = lambda v: np.isfinite(v) and v > 0  # noqa: E731
    p.filename = get("filename", None, str)
    p.storage = get("storage", DEFAULT_STORAGE, str, lambda v: v in PLUGIN_STORAGES,
                    "one of " + ", ".join(PLUGIN_STORAGES))
    if p.storage == "procedural":
        if p.filename is not None:
            bad.append("discrete medium: storage = procedural generates its particles (count, distribution); "
                       "a particle file is stored: use storage = compact or full with filename")
        p.count = get("count", 10000, int, lambda v: 1 <= v <= MAX_PROCEDURAL_COUNT,
                      f"an integer in [1, {MAX_PROCEDURAL_COUNT:g}] (storage = procedural)")
    else:
        p.count = get("count", 10000, int, lambda v: 1 <= v <= 10**9,
                      "an integer in [1, 1e9] (more with storage = procedural)")
        # The least any medium of this count needs (a dense cloud); the build checks its own estimate again.
        _memory.require(_memory.BYTES_PER_PARTICLE_DENSE * p.count, f"discrete medium: count = {p.count}")
    p.distribution = get("distribution", "uniform", str, lambda v: v in ("uniform", "gradient", "noise"),
                         "one of uniform, gradient, noise")
    lo_um, hi_um = psd_mod.LogNormal.r_min_um, psd_mod.LogNormal.r_max_um
    p.median = get("radius_median", 20.0, float, lambda v: lo_um < v < hi_um,
                   f"in ({lo_um:g}, {hi_um:g}) um (the log-normal PSD is truncated there; a wider one via psd)")
    p.sigma_g = get("radius_sigma_g", 1.5, float, lambda v: np.isfinite(v) and v >= 1, "finite and >= 1")
    p.psd_json = get("psd", None, str)
    p.material = get("material", None, str)
    p.eta = get("eta", 1.31, float, pos_f, "finite and > 0")
    p.eta_k = get("eta_k", 0.0, float, lambda v: np.isfinite(v) and v >= 0, "finite and >= 0")
    p.eta_medium = get("eta_medium", 1.0, float, pos_f, "finite and > 0")
    p.species_json = get("species", None, str)
    p.scale_m = get("scale_m", 1e-3, float, pos_f, "finite and > 0 (metres per unit)")


def _read_rendering(props, p: SimpleNamespace, bad: list, get) -> None:
    """How the medium is rendered: query radius (or Eq. 23), grid, optics tables, level of detail, storage cache, wavelengths, seed and albedo (``_read_parameters``)."""
    pos_f = lambda v: np.isfinite(v) and v > 0  # noqa: E731
    p.query_radius = get("query_radius", None, float)
    p.k = get("footprint_k", None, float, lambda v: 0 < v <= 2, "in (0, 2] (the paper advises 0.5-1)")
    p.fov = get("fov", None, float, lambda v: 0 < v < 180, "in (0, 180) degrees")
    p.film_width = get("film_width", None, int, lambda v: v >= 1, "an integer >= 1 (pixels)")
    p.z_med = get("z_med", None, float, pos_f, "finite and > 0 (scene units)")
    eq23 = [name in props for name in ("footprint_k", "fov", "film_width", "z_med")]
    if any(eq23) and not all(eq23):
        bad.append("discrete medium: footprint_k needs fov, film_width and z_med (Eq. 23), all four")
    elif all(eq23) and p.query_radius is not None:
        bad.append("discrete medium: give query_radius or footprint_k (Eq. 23), not both")
    p.kernel = get("kernel", default_kernel(mi.variant()), str, lambda v: v in KERNELS, "one of " + ", ".join(KERNELS))
    problem = kernel_problem(p.kernel, mi.variant())
    if problem:
        bad.append(problem)
    p.cells = get("cells_per_particle", DRJIT_CELLS_PER_PARTICLE if p.kernel == "drjit" else DEFAULT_CELLS_PER_PARTICLE,
                  float)
    # query_radius, cells_per_particle, tau_max and continuous_count are range-checked by the core
    # (motes._motes.check_discrete_inputs) before any table is built: one home for those rules.
    p.size_bins = get("size_bins", 16, int, lambda v: 1 <= v <= 4096, "an integer in [1, 4096]")
    p.method = get("method", "auto", str, lambda v: v in ("auto", "mie", "goa", "hybrid"),
                   "one of auto, mie, goa, hybrid")
    p.truncate = get("truncate_below", None, float, lambda v: v < np.pi, "below pi radians (negative: the default)")
    if p.truncate is not None and p.truncate < 0:
        p.truncate = None
    p.tau_max = get("tau_max", DEFAULT_TAU_MAX, float)
    # Both kernels render continuous size classes as their field, stored or procedural (drjit_medium.py).
    p.continuous = get("continuous_count", DEFAULT_CONTINUOUS_COUNT, float)
    p.grain_depth = get("grain_depth", DEFAULT_GRAIN_DEPTH, int, lambda v: 1 <= v <= MAX_GRAIN_DEPTH,
                        f"an integer in [1, {MAX_GRAIN_DEPTH}]")
    p.surface_footprint = get("surface_footprint", True, bool)
    p.cache_mb = get("cache_mb", None, float, lambda v: np.isfinite(v) and v > 0, "finite and > 0 (megabytes)")
    if "cache_mb" in props and p.storage != "procedural":
        bad.append("discrete medium: cache_mb bounds a procedural cloud's bricks: it needs storage = procedural")
    p.wavelengths = get("wavelengths", None, str)
    p.lam = _collected(bad, _wavelengths, p.wavelengths)
    p.seed = get("seed", 0, int, lambda v: 0 <= v < 2**64, "an integer in [0, 2^64)")
    if _volume(props, "albedo") is not None:
        p.albedo = _collected(bad, _albedo_of_volume, _volume(props, "albedo"), p.lam)
    elif "albedo" in props and props.type("albedo") not in (mi.Properties.Type.Float, mi.Properties.Type.Integer):
        p.albedo = _channels(props, "albedo", p.lam, bad, bounded=True)  # rgb, spectrum: one per channel
    else:
        p.albedo = get("albedo", None, float, lambda v: 0 <= v <= 1, "in [0, 1]")


def _read_motion(props, p: SimpleNamespace, bad: list, get) -> None:
    """Moving grains: time, velocity, turbulence and wrap (``_read_parameters``)."""
    p.time = get("time", 0.0, float, np.isfinite, "finite (seconds)")
    p.velocity = _collected(bad, _vector, props, "velocity")
    p.velocity = np.zeros(3) if p.velocity is None else p.velocity
    p.turbulence = get("turbulence", 0.0, float, lambda v: np.isfinite(v) and v >= 0, "finite and >= 0 (scene units)")
    p.turbulence_scale = get("turbulence_scale", None, float, lambda v: np.isfinite(v) and v > 0,
                             "finite and > 0 (scene units)")
    p.wrap = get("wrap", False, bool)
    p.moving = bool(np.any(p.velocity != 0) or p.turbulence > 0)
    with np.errstate(over="ignore", invalid="ignore"):
        shift = p.velocity * p.time
    if not np.all(np.isfinite(shift)):
        bad.append(f"discrete medium: velocity = {_fmt_channels(p.velocity)} times time = {p.time:g} s overflows: the grains "
                   "would move beyond any finite position (lower velocity or time)")
    if p.filename is not None and (p.moving or "time" in props):
        bad.append("discrete medium: time, velocity and turbulence move generated grains; a particle file "
                   "is read as it is (one file per frame: filename=\"grains_$frame.npz\")")
    if p.storage == "procedural" and p.wrap:
        bad.append("discrete medium: wrap needs stored grains (storage = compact or full); a procedural "
                   "cloud moves with velocity and turbulence")


def _shown(props, name: str) -> str:
    try:
        value = props.get(name)
    except Exception:  # noqa: BLE001 - an object Mitsuba cannot hand back: name its type
        return f"<{props.type(name).name}>"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _read_homogeneous_keys(props, p: SimpleNamespace, bad: list, get) -> None:
    """What Mitsuba's ``homogeneous`` medium takes (module docs, "From a homogeneous medium"): ``sigma_t`` (a
    float, rgb or spectrum per scene unit, read as ``homogeneous`` reads it) times ``scale`` sets the number of
    grains (``p.sigma_t``: per channel; None: neither given); ``has_spectral_extinction`` is read and, where it
    asks for what the grains do not do, said once."""
    scale = get("scale", None, float, lambda v: np.isfinite(v) and v > 0, "finite and > 0 (it multiplies sigma_t)")
    p.sigma_t = None
    p.density = _DENSITIES.get(p.distribution, _DENSITIES["uniform"])
    volume = _volume(props, "sigma_t")
    if volume is not None:
        p.sigma_t = _collected(bad, _density_of_volume, volume, p, props)
    elif "sigma_t" in props:
        p.sigma_t = _channels(props, "sigma_t", p.lam, bad, bounded=False)
    elif scale is not None and p.lam is not None:
        p.sigma_t = np.ones(p.lam.size)  # homogeneous's default sigma_t, 1
    if p.sigma_t is not None:
        if not np.all(np.isfinite(p.sigma_t) & (p.sigma_t >= 0)) or not np.mean(p.sigma_t) > 0:
            bad.append(f"discrete medium: invalid sigma_t = {_fmt_channels(p.sigma_t)}: must be finite, >= 0 and not "
                       "all zero (a discrete medium holds at least one grain)")
        p.sigma_t = p.sigma_t * (1.0 if scale is None else scale)
    given = "sigma_t" if "sigma_t" in props else "scale (times sigma_t, 1 by default)" if "scale" in props else None
    for other, what in (("count", "the number of generated grains"), ("filename", "a file's grains")):
        if given is not None and other in props:
            bad.append(f"discrete medium: {other} and {given} both set the grains: give one ({other}: {what}; "
                       "sigma_t: the bulk extinction per scene unit, as homogeneous takes it, times scale)")
    p.spectral_extinction = get("has_spectral_extinction", False, bool)


def _volume(props, name: str):
    """The parameter ``name`` where it is a volume (``heterogeneous``'s way: ``<volume name=...>``), else None."""
    if name not in props or props.type(name) != mi.Properties.Type.Object:
        return None
    obj = props.get(name)
    return obj if isinstance(obj, mi.Volume) else None


def _volume_box(volume) -> tuple[np.ndarray, np.ndarray]:
    box = volume.bbox()
    return tuple(np.asarray(v, dtype=np.float64).ravel()[:3] for v in (box.min, box.max))


def _grid_values(volume) -> np.ndarray:
    """A ``gridvolume``'s values as (nz, ny, nx, channels) float64; a ``constvolume`` as one cell."""
    params = mi.traverse(volume)
    if "data" in params:
        return np.asarray(params["data"], dtype=np.float64)
    if volume.class_name() == "ConstVolume":
        it = dr.zeros(mi.Interaction3f)
        value = np.asarray(volume.eval(it), dtype=np.float64).ravel()
        return value.reshape(1, 1, 1, -1)
    raise ValueError(f"discrete medium: a {volume.class_name()} cannot give the grains' density: use a gridvolume "
                     "or a constvolume")


def _density_of_volume(volume, p: SimpleNamespace, props) -> np.ndarray:
    """A ``sigma_t`` volume (module docs, "From a heterogeneous medium"): sets ``p.density`` (the core's grid) and
    ``p.to_world`` (the volume's box), and returns the mean sigma_t per channel (before ``scale``)."""
    for clash in ("to_world", "distribution"):
        if clash in props:
            raise ValueError(f"discrete medium: sigma_t is a volume, which places the grains (its own to_world) and "
                             f"sets their density: remove the medium's {clash}")
    values = _grid_values(volume)
    if not (np.all(np.isfinite(values)) and np.all(values >= 0) and values.mean() > 0):
        raise ValueError("discrete medium: the sigma_t volume's values must be finite, >= 0 and not all zero")
    channels = values.mean(axis=(0, 1, 2))
    grey = values.mean(axis=3)
    lo, hi = _volume_box(volume)
    if not np.all(hi > lo):
        raise ValueError(f"discrete medium: the sigma_t volume's box {lo.tolist()}..{hi.tolist()} is empty")
    # Its box places it only where its to_world neither rotates nor shears it: the volume's own values at
    # points of the box must be the grid's at the same place.
    rng = np.random.default_rng(1)
    u = rng.random((64, 3))
    pts = lo + u * (hi - lo)

    def at(k: int):
        it = dr.zeros(mi.Interaction3f)
        it.p = mi.Point3f(*(float(c) for c in pts[k]))
        return it

    # (One point at a time: the same call in scalar and vectorised variants.)
    theirs = None
    if values.shape[3] == 1:
        theirs = np.array([float(np.asarray(volume.eval_1(at(k))).ravel()[0]) for k in range(len(u))])
    elif values.shape[3] == 3:
        theirs = np.array([np.asarray(volume.eval_3(at(k)), dtype=np.float64).ravel()[:3].mean() for k in range(len(u))])
    nz, ny, nx = grey.shape
    grid = np.concatenate([[nx, ny, nz], grey.ravel()])
    ours = _motes.density_at("grid", grid, 0, np.ascontiguousarray(u, dtype=np.float64).ravel(), [0.0] * 3, [1.0] * 3)
    if theirs is not None and not np.allclose(theirs, ours, rtol=1e-3, atol=1e-6 * grey.max()):
        raise ValueError("discrete medium: the sigma_t gridvolume's to_world rotates or shears it; the grains take a "
                         "grid placed by translation and scale only")
    if np.ptp(channels) > 1e-6 * channels.mean():
        warnings.warn(f"discrete medium: the sigma_t volume is coloured (channel means {_fmt_channels(channels)}); "
                      "the grains' extinction is grey, so their density follows its channels' mean (colour them "
                      "with albedo)", stacklevel=5)
    p.density = ("grid", grid)
    box = np.eye(4)
    box[:3, :3] *= (hi - lo) / 2
    box[:3, 3] = (hi + lo) / 2
    p.to_world, p.to_world_given = mi.ScalarTransform4f(box.tolist()), True
    lam_size = 1 if p.lam is None else p.lam.size
    return np.full(lam_size, float(grey.mean()))


def _albedo_of_volume(volume, lam) -> np.ndarray:
    """An ``albedo`` volume's mean per channel (a grain's albedo does not vary in space), said in one line."""
    values = _grid_values(volume)
    channels = values.mean(axis=(0, 1, 2))
    if not np.all(np.isfinite(values) & (values >= 0) & (values <= 1)):
        raise ValueError("discrete medium: the albedo volume's values must be in [0, 1]")
    size = 1 if lam is None else lam.size
    out = channels if channels.size == size else np.full(size, float(channels.mean()))
    warnings.warn(f"discrete medium: the albedo volume is taken as its mean {_fmt_channels(out)} (a grain's albedo "
                  "does not vary in space)", stacklevel=5)
    return out


def _channels(props, name: str, lam, bad: list, bounded: bool):
    """A colour parameter read as Mitsuba's ``homogeneous`` medium reads it (a texture: float, rgb or
    spectrum) and evaluated at each channel (``_spectrum_values``), or None with the problem added to ``bad``."""
    if bounded and props.type(name) == mi.Properties.Type.Color:  # Mitsuba's own check names no parameter
        rgb = np.array([float(c) for c in props.get(name)])
        if not np.all(np.isfinite(rgb) & (rgb >= 0) & (rgb <= 1)):
            bad.append(f"discrete medium: invalid {name} = {_fmt_channels(rgb)}: each channel must be in [0, 1]")
            return None
    try:
        if bounded:
            tex = props.get_texture(name)
        else:
            # As homogeneous reads sigma_t (a bounded spectrum, e.g. an rgb in [0, 1] times scale), and beyond 1
            # as an unbounded one.
            try:
                tex = props.get_texture(name)
            except Exception:  # noqa: BLE001 - Mitsuba refuses an rgb above 1 as a bounded spectrum
                tex = props.get_unbounded_texture(name)
    except Exception as e:  # noqa: BLE001 - Mitsuba's own words for what it could not read
        bad.append(f"discrete medium: invalid {name} ({' '.join(str(e).split())}): give a float, rgb or spectrum"
                   + (" with values in [0, 1]" if bounded else ""))
        return None
    if lam is None:
        return None
    values = _spectrum_values(tex, lam)
    if bounded and not np.all(np.isfinite(values) & (values >= 0) & (values <= 1)):
        bad.append(f"discrete medium: invalid {name} = {_fmt_channels(values)}: each channel must be in [0, 1]")
        return None
    return values


def _fmt_channels(v) -> str:
    return "(" + ", ".join(f"{float(x):.4g}" for x in np.atleast_1d(v)) + ")"


def _spectrum_values(tex, lam_um: np.ndarray) -> np.ndarray:
    """A Mitsuba texture's value at each channel of the medium, in channel order: R, G, B in RGB variants
    (``lam_um`` holds their wavelengths), the spectrum at each wavelength of ``lam_um`` in spectral ones."""
    si = dr.zeros(mi.SurfaceInteraction3f)
    if not mi.is_spectral:
        v = tex.eval(si)
        out = np.array([float(np.asarray(v[c]).ravel()[0]) for c in range(dr.size_v(mi.UnpolarizedSpectrum))])
        return out if out.size == lam_um.size else np.full(lam_um.size, float(out.mean()))
    nm = [float(x) * 1e3 for x in lam_um]
    size = dr.size_v(mi.UnpolarizedSpectrum)
    out = []
    for i in range(0, len(nm), size):
        chunk = nm[i:i + size]
        si.wavelengths = type(si.wavelengths)(chunk + [chunk[-1]] * (size - len(chunk)))
        v = tex.eval(si)
        out += [float(np.asarray(v[c]).ravel()[0]) for c in range(len(chunk))]
    return np.array(out)


def _count_of_extinction(p: SimpleNamespace, species: list, lam: np.ndarray, truncate: float | None,
                         volume: float | None = None, where: str = "the medium's box") -> float:
    """The number of grains whose bulk extinction is ``p.sigma_t`` (per scene unit; its mean over the channels)
    in ``volume`` (scene units^3; None: the medium's box, ``to_world`` of the local cube [-1, 1]^3; a filled medium:
    the inside of the shapes that hold it, ``where`` says which): n = sigma_t / <C_ext> per m^3 with the
    grains' own mean grey C_ext (``motes.discrete.mean_extinction_um2``: each bin's truncated Q_ext times
    pi r^2, as the medium gives each grain), times the box's volume. An integer for stored grains, the
    Poisson mean of a procedural cloud."""
    sigma = float(np.mean(p.sigma_t))
    if np.ptp(p.sigma_t) > 1e-6 * sigma:
        warnings.warn(f"discrete medium: sigma_t = {_fmt_channels(p.sigma_t)} per unit is coloured; the grains' "
                      f"extinction is grey, so their number follows its mean over the channels, {sigma:.4g} per unit "
                      "(colour them with albedo)", stacklevel=4)
    c_um2 = mean_extinction_um2(species, lam, size_bins=p.size_bins, eta_medium=p.eta_medium, method=p.method,
                                truncate_below_rad=truncate)
    if volume is None:
        volume = 8.0 * abs(float(np.linalg.det(_checked_to_world(p)[:3, :3])))  # scene units^3
    count = sigma * volume * p.scale_m**2 / (c_um2 * 1e-12)
    what = (f"sigma_t = {sigma:.4g} per unit over {where} ({volume:.4g} units^3, scale_m = {p.scale_m:g} m) "
            f"with grains of mean C_ext {c_um2:.4g} um^2 is {count:.4g} grains")
    if p.storage == "procedural":
        if not 1 <= count <= MAX_PROCEDURAL_COUNT:
            raise ValueError(f"discrete medium: {what}: a procedural cloud takes 1 to {MAX_PROCEDURAL_COUNT:g} "
                             "(change sigma_t, the grains' size or scale_m)")
    else:
        count = int(round(count))
        if count < 1:
            raise ValueError(f"discrete medium: {what}: fewer than one; raise sigma_t or take smaller grains "
                             "(radius_median)")
        if count > 10**9:
            raise ValueError(f"discrete medium: {what}, more than a stored cloud takes (1e9): use storage = "
                             "procedural (up to 1e15), larger grains (radius_median) or a smaller scale_m")
        _memory.require(_memory.BYTES_PER_PARTICLE_DENSE * count, f"discrete medium: sigma_t = {sigma:.4g} ({count} grains)")
    log.info("sigma_t: %.4g per unit is %.6g grains of mean C_ext %.4g um^2 in %.4g units^3", sigma, count, c_um2,
             volume)
    return count


def _vector(props, name: str) -> np.ndarray:
    """A 3-vector parameter (``<vector name=... value="x, y, z"/>``), finite; zeros when absent."""
    if name not in props:
        return np.zeros(3)
    value = props.get(name)
    try:
        v = np.array([float(value[i]) for i in range(3)])
    except (TypeError, IndexError, ValueError):
        raise ValueError(f"discrete medium: parameter '{name}' must be a vector (x, y, z), got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise ValueError(f"discrete medium: invalid {name} = {v.tolist()}: must be finite")
    return v


#: How a parameter's type reads in a message.
_KIND_NAMES = {int: "an integer", float: "a number", str: "a string", bool: "a boolean"}


def _get(props, name, default, kind, check=None, allowed="", bad: list | None = None):
    """Read a property (so Mitsuba counts it as used), check its type and range. A problem raises a
    ValueError, or with ``bad`` is added to it (and the default returned)."""
    if name not in props:
        return default
    value = given = props.get(name)
    if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        value = float(value)
    elif kind is int and isinstance(value, float) and value.is_integer():
        value = int(value)  # an integer given as a float (1e308 too: checked, and shown, as given)
    problem = None
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        problem = f"discrete medium: parameter '{name}' must be {_KIND_NAMES.get(kind, kind.__name__)}, got {given!r}"
    elif check is not None and not check(value):
        problem = f"discrete medium: invalid {name} = {given!r}: must be {allowed}"
    if problem is None:
        return value
    if bad is None:
        raise ValueError(problem)
    bad.append(problem)
    return default


def _species(p: SimpleNamespace, props) -> list:
    """The species: the ``species`` JSON list, or one species of ``psd`` (or the log-normal) and material/eta."""
    if p.species_json is not None:
        try:
            entries = json.loads(p.species_json)
        except json.JSONDecodeError as e:
            raise ValueError(f"discrete medium: parameter 'species' is not valid JSON ({e})") from None
        if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
            raise ValueError("discrete medium: parameter 'species' must be a non-empty JSON list of objects")
        return [_species_entry(e, i) for i, e in enumerate(entries)]
    psd = psd_mod.from_spec(p.psd_json) if p.psd_json is not None else psd_mod.LogNormal(p.median, p.sigma_g)
    return [Species(psd, Material(p.material) if p.material is not None else complex(p.eta, p.eta_k))]


#: Keys a species entry may hold (a misspelt key is an error, not silently ignored).
SPECIES_KEYS = ("psd", "material", "eta", "share", "name")


def _eta(entry, where):
    if "material" in entry and "eta" in entry:
        raise ValueError(f'discrete medium: {where} gives both "material" and "eta"; keep one')
    if "material" in entry:
        return Material(str(entry["material"]))
    if "eta" in entry:
        e = entry["eta"]
        try:
            if isinstance(e, (list, tuple)):
                if len(e) != 2:
                    raise ValueError
                e = complex(float(e[0]), float(e[1]))
            else:
                e = complex(float(e), 0.0)
        except (TypeError, ValueError):
            raise ValueError(f'discrete medium: {where} "eta" must be a number n or a pair [n, k], got {entry["eta"]!r}') from None
        if not (np.isfinite(e.real) and e.real > 0 and e.imag >= 0):
            raise ValueError(f"discrete medium: invalid eta {e} in {where}: real part > 0, imaginary >= 0")
        return e
    raise ValueError(f'discrete medium: {where} needs "material" or "eta"')


def _species_entry(e: dict, i: int) -> Species:
    where = f"species[{i}]"
    unknown = sorted(set(e) - set(SPECIES_KEYS))
    if unknown:
        raise ValueError(f"discrete medium: {where} has unknown key(s) {', '.join(map(repr, unknown))}; "
                         f"allowed: {', '.join(SPECIES_KEYS)}")
    share = e.get("share", 1.0)
    if isinstance(share, bool) or not isinstance(share, (int, float)) or not (np.isfinite(share) and share >= 0):
        raise ValueError(f'discrete medium: {where} "share" must be a number >= 0, got {share!r}')
    return Species(psd_mod.from_spec(e.get("psd", {})), _eta(e, where), float(share))


def _particles(p: SimpleNamespace, props, species: list):
    """Positions (scene units, after ``to_world``), radii (um) and species indices: read from ``filename`` or generated."""
    t_particles = time.perf_counter()
    m = _checked_to_world(p)
    if p.filename is not None:
        pos, radii, sidx = _read_particles(p, props, species)
        pos = _transformed_in_place(pos, m)
    else:
        pos, radii, sidx = _generated_particles(p, species, m)
    log.info("particles: %d %s in %.1f s", len(pos), "read" if p.filename is not None else "generated",
             time.perf_counter() - t_particles)
    return pos, radii, sidx


def _density_drawn_from(p: SimpleNamespace):
    """The density generated grains were drawn from (``DiscreteMedium``'s ``density``: their continuous equivalent
    follows it); None for grains read from a file or moved since."""
    if p.filename is not None or (p.moving and p.time != 0):
        return None
    kind, params = p.density
    m = _checked_to_world(p)
    return kind, [float(x) for x in params], int(p.seed), [-1.0] * 3, [1.0] * 3, m[:3, :4].tolist()


def _checked_to_world(p: SimpleNamespace) -> np.ndarray:
    """``to_world`` as a 4x4 array, checked to be finite and invertible."""
    m = np.array(p.to_world.matrix, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise ValueError("discrete medium: to_world is not finite (Mitsuba keeps transforms in single precision: "
                         "a scale or translation beyond 3.4e38 is infinite)")
    a = m[:3, :3] / max(np.abs(m[:3, :3]).max(), 1e-300)  # its determinant without overflow (a scale of 1e30)
    if not abs(np.linalg.det(a)) > 1e-12:
        raise ValueError("discrete medium: to_world is singular (a zero scale?)")
    return m


def _transformed_in_place(pos: np.ndarray, m: np.ndarray, chunk: int = 1 << 20) -> np.ndarray:
    """``pos`` (n, 3) mapped by the affine ``m`` (4x4) chunk by chunk, in place where it can be (a file's
    1e8 positions are 2.4 GB: no full-size temporaries)."""
    pos = np.require(pos, dtype=np.float64, requirements=["C", "W"])
    a, b = m[:3, :3].T, m[:3, 3]
    for i in range(0, pos.shape[0], chunk):
        pos[i:i + chunk] = pos[i:i + chunk] @ a + b
    return pos


def _read_particles(p: SimpleNamespace, props, species: list):
    """The particles of ``filename`` (local units): positions, radii (um), species indices."""
    clash = [name for name in ("count", "distribution") if name in props]
    if clash:
        raise ValueError(f"discrete medium: {', '.join(clash)} set the generated particles; with filename "
                         "the particles come from the file — remove one or the other")
    path = _particle_file(p.filename)
    # scale_m converts a PLY's Houdini `pscale` (radii in scene units) to micrometres.
    try:
        pset = load_particles(path, scale_m=p.scale_m, n_species=len(species))
    except ParticleFileError as exc:
        raise ParticleFileError(f"discrete medium: filename = {p.filename!r}: {exc}") from None
    r_lo, r_hi = float(pset.radii_um.min()), float(pset.radii_um.max())
    if r_hi > 1e5 or r_lo < 1e-3:
        raise ValueError(f"discrete medium: {path}: particle radii from {r_lo:g} to {r_hi:g} um are implausible "
                         f"(field radius_um / radius in um, or a PLY pscale in scene units times scale_m = {p.scale_m:g} m)")
    return pset.positions, pset.radii_um, pset.species


def _particle_file(name: str) -> str:
    """``filename`` resolved as Mitsuba resolves meshes and textures: a relative name against the scene file's
    folder, then the file resolver's other folders; never an empty name (it would resolve to a folder)."""
    if not name.strip():
        raise ValueError("discrete medium: filename is empty: give the particle file's path (absolute, or relative "
                         "to the scene file's folder)")
    path = str(mi.file_resolver().resolve(name))
    if not os.path.isabs(path):  # in none of the resolver's folders (resolve() returns such a name unchanged)
        folders = ", ".join(str(d) for d in mi.file_resolver())
        raise ParticleFileError(f"discrete medium: filename = {name!r}: no such file (a relative name is looked up "
                                f"in the scene file's folder and Mitsuba's search path: {folders})")
    return path


#: ``distribution`` -> the core's density (``motes_core::space::cloud``) and its parameters: a gradient from
#: 1 on the local cube's z = -1 face to 0 on z = 1; fBm noise of scale 0.5 (4 octaves, contrast 1).
_DENSITIES = {"uniform": ("uniform", []), "gradient": ("gradient", [2, 1.0, 0.0]), "noise": ("noise", [0.5, 4, 1.0])}


def _procedural(p: SimpleNamespace, species: list, lam, common: dict) -> DiscreteMedium:
    """A procedural cloud of ``count`` particles in the local cube [-1, 1]^3 (``storage = procedural``):
    the distribution, species and seed as a generated cloud's, no particle stored. A velocity moves the
    whole cloud (its to_world translated by velocity x time), grain by grain as a stored cloud's."""
    m = _checked_to_world(p).copy()
    m[:3, 3] += p.velocity * p.time
    shares = species_shares(species)
    corners = np.array([[(-1.0, 1.0)[(i >> a) & 1] for a in range(3)] for i in range(8)]) @ m[:3, :3].T + m[:3, 3]
    query_radius, _ = _query_radius(p, corners)
    t = time.perf_counter()
    data = DiscreteMedium.procedural(p.count, species, shares, lam, box=((-1.0,) * 3, (1.0,) * 3),
                                     density=p.density, noise_seed=p.seed, cloud_seed=p.seed,
                                     to_world=m, query_radius=query_radius,
                                     cache_bytes=None if p.cache_mb is None else max(int(p.cache_mb * 2**20), 1),
                                     turbulence=p.turbulence, turbulence_scale=_turbulence_scale(p, m), time_s=p.time,
                                     **common)
    log.info("particles: %.3g procedural (none stored) in %.1f s", p.count, time.perf_counter() - t)
    return data


def _generated_particles(p: SimpleNamespace, species: list, to_world: np.ndarray):
    """``count`` particles in the local cube [-1, 1]^3 after ``distribution``, mapped by ``to_world``
    (generated in the core, tile by tile: ``motes_core::space::cloud``): positions, radii (um), species."""
    shares = species_shares(species)
    kind, params = p.density
    pos, radii, sidx = _motes.generate_cloud(p.count, [-1.0] * 3, [1.0] * 3, kind, params, p.seed,
                                             [s.psd._core for s in species], shares, p.seed,
                                             to_world[:3, :4].tolist())
    if p.moving and p.time != 0:
        pos = _motes.move_grains(pos, p.velocity.tolist(), p.turbulence, _turbulence_scale(p, to_world), p.seed, p.time,
                                 to_world[:3, :4].tolist() if p.wrap else None)
    return pos.reshape(-1, 3), radii, sidx


def _turbulence_scale(p: SimpleNamespace, to_world: np.ndarray) -> float:
    """``turbulence_scale``, or a quarter of the cloud's largest extent (its local cube through to_world)."""
    if p.turbulence_scale is not None:
        return p.turbulence_scale
    return 0.25 * 2.0 * float(np.abs(to_world[:3, :3]).sum(axis=1).max())


def _query_radius(p: SimpleNamespace, pos: np.ndarray):
    """(r_c, whether the user set it): ``query_radius``, Eq. 23 from ``footprint_k``, or 0."""
    query_radius = p.query_radius
    if all(v is not None for v in (p.k, p.fov, p.film_width, p.z_med)):  # Eq. 23 (_read_parameters checked the four)
        query_radius = query_radius_from_camera(p.k, p.fov, p.film_width, p.z_med)
    user_radius = query_radius is not None
    query_radius = 0.0 if query_radius is None else query_radius
    extent = float(np.min(np.subtract(*box_of(pos)[::-1]))) if len(pos) > 1 else 0.0
    # (A radius beyond what the renderer holds, single precision, is the core's error, said alone.)
    if extent > 0 and query_radius <= float(np.finfo(np.float32).max) and query_radius > 0.25 * extent:
        # stacklevel 3: the caller of the plugin's constructor, past this function and __init__.
        warnings.warn(f"discrete medium: query_radius = {query_radius:g} is comparable to the particles' extent "
                      f"({extent:g} scene units): disks reaching out of the box lose their extinction there", stacklevel=3)
    return query_radius, user_radius


def _wavelengths(wavelengths: str | None) -> np.ndarray:
    """The tabulated wavelengths (um): ``wavelengths``, or the variant's defaults."""
    if wavelengths is None:
        return np.array(RGB_WAVELENGTHS_UM if mi.is_rgb else SPECTRAL_WAVELENGTHS_UM)
    try:
        lam = np.array([float(x) for x in wavelengths.replace(",", " ").split()])
    except ValueError:
        raise ValueError(f"discrete medium: parameter 'wavelengths' must be numbers in um, got {wavelengths!r}") from None
    if mi.is_rgb and lam.size != 3:
        raise ValueError("discrete medium: RGB variants need exactly 3 wavelengths (R, G, B)")
    problem = implausible_wavelengths(lam, "wavelengths")
    if problem is not None:
        raise ValueError(f"discrete medium: invalid {problem}")
    return lam


# -- Native render path ----------------------------------------------------------------------------
def native_in_use() -> bool:
    """Whether the current variant renders through the native plugins (``motes.native``)."""
    return mi.variant() in native.loaded_variants()


def _polarizing(p: SimpleNamespace) -> bool:
    """Whether the medium's phase function returns the grains' Mueller matrices: in polarised variants, where
    the phase function is the grains' own (a user's ``phase`` and ``phase_model = "hg"`` depolarise, as
    Mitsuba's own phase functions do)."""
    return bool(mi.is_polarized) and p.phase is None and p.phase_model == "tabulated"


def _native_objects(handles: list, lam_um, sample_emitters: bool, description: str, polarizing: bool = False):
    """The native phase function and medium over two native handles (``handles``: on a built Rust medium, each a
    reference to it and to its data, ``native_data``; or pending ones, ``_scene.PendingFill``) of a medium whose
    channels are at ``lam_um`` (``motes/native/motes_native.cpp``); ``polarizing``: ``_polarizing``."""
    from .. import _motes

    def common(handle):
        d = {"api": int(_motes.NATIVE_API), "medium": int(handle)}
        if mi.is_rgb:
            d.update({f"channel_nm_{c}": float(x) * 1e3 for c, x in enumerate(lam_um)})
        elif not mi.is_spectral:  # monochrome: the middle tabulated wavelength (_bridge.channel_wavelengths)
            d["channel_nm_0"] = float(np.asarray(lam_um)[np.asarray(lam_um).size // 2]) * 1e3
        return d

    # Mitsuba's own loader: the wrapped one (scene_checks) would fill a pending medium it returned as one used alone.
    load_dict = getattr(mi.load_dict, "__wrapped__", mi.load_dict)
    phase = load_dict({"type": "motes_particle_native", "description": f"ParticlePhase[of {description}]",
                       "polarizing": bool(polarizing), **common(handles[0])})
    medium = load_dict({"type": "motes_discrete_native", "sample_emitters": sample_emitters, "phase": phase,
                           "description": description, **common(handles[1])})
    return medium, phase


def _data_of_native(medium) -> DiscreteMedium:
    data = native_data(medium)
    pending = pending_of(medium) if data is None else None
    if pending is not None:  # used alone: made now in its local cube (PendingFill.result)
        data = pending.result()
    if data is None:
        raise AttributeError(f"'{type(medium).__name__}' object has no attribute 'data' (not a discrete medium)")
    return data


def _stats(core, evaluated: dict) -> dict:
    """The ``stats`` of a discrete medium: the evaluated-mode path's counters plus the native path's rays
    and events (kept by the Rust medium)."""
    rays, events = core.native_counts
    return dict(evaluated, rays=evaluated["rays"] + rays, events=evaluated["events"] + events)


#: The evaluated-mode counters of a medium that never used that path.
_NO_EVALUATED_CALLS = {"intersect_calls": 0, "rays": 0, "events": 0, "nulls": 0}


def _stats_of_native(medium) -> dict:
    return _stats(_data_of_native(medium).core, _NO_EVALUATED_CALLS)


class _NativeAccessor:
    """A read-only attribute of native ``discrete`` media on ``mi.Medium``. A non-data descriptor (no
    ``__set__``): an instance attribute of the same name, as any Python medium may set, still wins."""

    def __init__(self, get, doc: str):
        self._get, self.__doc__ = get, doc

    def __get__(self, obj, owner=None):
        return self if obj is None else self._get(obj)


def install_native_accessors() -> None:
    """``data`` and ``stats`` on the current variant's ``mi.Medium``, answering for native ``discrete``
    media (other media: AttributeError), as the Python plugin answers them."""
    if not isinstance(mi.Medium.__dict__.get("data"), _NativeAccessor):
        mi.Medium.data = _NativeAccessor(_data_of_native, "The particles and optics of a discrete medium.")
        mi.Medium.stats = _NativeAccessor(_stats_of_native, "Render counters of a discrete medium.")


def factory():
    """What Mitsuba calls to make a ``discrete`` medium in the current variant: the Python plugin, or in
    scalar variants with the native path its native medium itself (module docs, "Render paths")."""
    cls = plugin_class()
    if is_jit() or not native_in_use():
        return cls
    install_native_accessors()

    def make(props):
        medium = cls(props)._native
        medium.set_id(props.id())  # the scene's name for it (mi.traverse keys, <ref id=...>)
        return medium

    return make


_classes: dict = {}


def plugin_class():
    """The plugin class for the current Mitsuba variant."""
    return bind_to_variant(DiscreteMediumPlugin, "Medium", "DiscreteMedium", _classes)

