"""The discrete medium's data, independent of Mitsuba: particles in a grid with the optics the renderer
queries (``rust/motes-core/src/render/discrete/mod.rs`` documents the model).

``DiscreteMedium(positions, radii_um, species_index, species, ...)``

==========================  ==========================================================================
``positions``               (n, 3) particle centres, scene units
``radii_um``                (n,) radii, micrometres
``species_index``           (n,) index into ``species`` (a list of ``motes.Species``; their PSDs only set
                            the radius range of the optics bins, the radii come from ``radii_um``). A
                            species of the host's index (eta = ``eta_medium``, no absorption) is a
                            ValueError: its grains neither scatter nor absorb
``wavelength_um``           tabulated wavelengths: the RGB channels' three (in channel order), or the
                            spectral samples (wavelengths in between are interpolated linearly); one
                            outside 0.01-100 um warns (nanometres given as micrometres, most likely)
``scale_m``                 metres per scene unit
``query_radius``            r_c, scene units (``motes.query_radius_from_camera`` gives Eq. 23's)
``tau_max``                 cap on each particle's optical depth (``DEFAULT_TAU_MAX`` = 1): a particle
                            whose disk r_c + r_i would be more opaque is given a wider one, and each
                            disk's depth is -ln(1 - C/(pi R^2)) so that it removes exactly its C_ext
                            from a beam whatever r_c (``rust/motes-core/src/render/discrete/mod.rs``); inf: no cap
``size_bins``               radius bins per species (log-spaced over its particles' radii); each bin's
                            albedo, efficiencies and phase function are the ensemble of a uniform
                            distribution over the bin (Eq. 16-17), which also smooths Mie ripples
``truncate_below_rad``      forward-peak truncation per bin (delta-M, see ``bulk_properties``); default
                            ``DEFAULT_TRUNCATE_RAD`` (0.031 rad, one bin of a 4096-value ``tabphase``,
                            as ``homogeneous_equivalent``); None or 0: none
``cells_per_particle``      grid resolution (``DEFAULT_CELLS_PER_PARTICLE`` = 0.125: about eight particles per cell),
                            at most 2e8 / n (a grid takes at most 2e8 cells; more is a ValueError naming it); the
                            cells count in the memory estimate checked before the build (``motes._memory``)
``continuous_count``        size classes (factors of two in r_c + r_i) whose particles a query cylinder
                            holds at least this many of, over one mean free path or across the cloud
                            (``DEFAULT_CONTINUOUS_COUNT`` = 16), are sampled as a continuous medium of
                            the same mean extinction and local phase mixture: no pixel resolves their
                            grains, and they cost about what ``homogeneous`` costs
                            (``rust/motes-core/src/render/continuous/``); inf: every particle discrete
``grain_depth``             a path's rays see grains one by one until its ``grain_depth``-th scattering
                            event (``DEFAULT_GRAIN_DEPTH`` = 1); rays leaving that event or a later one
                            see the grains' continuous equivalent (same extinction per cell and local
                            phase mixture; Müller et al. 2016, Sec. 4.3) where their pixel footprint
                            holds ``continuous_count`` grains, as rays from surfaces (without cameras:
                            never, they walk the grains). Ignored when
                            ``continuous_count`` is inf, which makes the medium exact. In [1, 2^32 - 1]
``surface_footprint``       rays that start at no event (a surface, a boundary, a camera) see the grains'
                            continuous equivalent where the narrowest pixel footprint they can carry
                            (from the cameras given to ``set_cameras``; the Mitsuba plugin reads them
                            from the scene) holds ``continuous_count`` grains (an effective count over
                            the discrete size classes); a camera ray also needs 2.5 grains per sample
                            per pixel of the render, so that their texture stays below its noise
                            (``rust/motes-core/src/render/footprint.rs``; True; without cameras
                            nothing changes)
``storage``                 ``compact`` (default): each particle is a class of its optics bin and one of
                            1024 radius levels per bin (radii move by at most half a level, 2e-4 for a
                            bin 1.5 wide), stored once, by its centre's grid cell, its centre on a
                            lattice of 6e-5 of a cell (from 65536 discrete grains up: 11-14 bytes per
                            discrete grain in all), and the
                            per-particle arrays below are not kept; ``full``: every particle's radius
                            as given, and ``positions``, ``radii_um``, ``species_index``,
                            ``particle_bin``, ``c_ext_scene`` kept for inspection
                            (``rust/motes-core/src/render/storage.rs``)
``seed``                    seed of the free-flight random numbers
``albedo``                  replaces every particle's single-scattering albedo (tests, stylisation;
                            default: the physical one): one number for every channel, or one per
                            channel in the order of ``wavelength_um`` as given, each in [0, 1]
``phase_model``             ``tabulated`` (default: each bin's ensemble phase function, Eq. 17) or
                            ``hg``: Henyey-Greenstein with the same asymmetry g per bin and wavelength
                            (the model graphics often uses instead; the paper's Fig. 13 comparison)
``phase``                   one phase function for every bin and wavelength instead of the grains' own
                            (a Mitsuba scene's ``<phase>`` child; ``phase_table`` builds it):
                            ``{"type": "isotropic"}``, ``{"type": "hg", "g": g}`` or ``{"type":
                            "tabphase", "values": [...]}`` (values on a regular grid of cos(theta) from
                            -1, backward, to 1, forward, as Mitsuba's ``tabphase``); None: the grains'
                            own (default). Extinction and albedo stay the grains'
``density``                 the density the particles were drawn from (a generated cloud): (kind, params,
                            noise seed, as ``generate_cloud``; the cloud's box lo and hi; its to_world,
                            3x4). The grains' continuous equivalent then follows it instead of their
                            counts in cells of 64, which flatten a concentrated density
                            (``DiscreteMedium::see_density`` in the Rust core); None: the counts
==========================  ==========================================================================

Each particle's extinction cross section is ``pi r^2 Q_ext`` with its bin's mean efficiency over the
wavelengths (grey, see the Rust docs for why), its albedo and phase function those of its bin per
wavelength. ``bin_radius_um``, ``bin_species``, ``bin_q_ext``, ``bin_albedo`` (the physical one) and
``bin_g`` (the mean cosine of the phase function the bin renders with) (per channel, in the order the
wavelengths were given) and ``particle_bin`` report what was built.

``mean_extinction_um2`` is the mean of that grey cross section over the species' PSDs (what a bulk
extinction sigma_t = n <C_ext> needs: the ``discrete`` plugin's ``sigma_t``).
"""

from __future__ import annotations

import numpy as np

import logging
import time
import warnings

from . import _memory, _motes
from .ensemble import DEFAULT_TRUNCATE_RAD, Material, Species, bulk_properties, species_list
from .psd import Monodisperse, Uniform

#: Load stages (optics tables, grid) and their times, at INFO (the `motes` command shows them).
log = logging.getLogger("motes")

#: Default cap on each particle's optical depth (module docs; defined in the Rust core).
DEFAULT_TAU_MAX: float = _motes.DEFAULT_TAU_MAX
#: Default particles per query cylinder from which a size class is continuous (module docs).
DEFAULT_CONTINUOUS_COUNT: float = _motes.DEFAULT_CONTINUOUS_COUNT
DEFAULT_CELLS_PER_PARTICLE: float = _motes.DEFAULT_CELLS_PER_PARTICLE
#: Default scattering event from which a path's rays see the grains' continuous equivalent (module docs).
DEFAULT_GRAIN_DEPTH: int = _motes.DEFAULT_GRAIN_DEPTH
#: A query radius that tau_max overrides for more than this share of the particles raises a warning (a few
#: of the largest grains in a log-normal tail are widened silently: they change nothing a user could see).
WIDENED_WARN_SHARE: float = 1e-3
#: How a medium stores its particles (module docs): ``compact`` (default) or ``full``.
STORAGES = ("compact", "full")
#: What ``phase_model`` takes: the tabulated ensemble phase function, or Henyey-Greenstein of the same g.
PHASE_MODELS = ("tabulated", "hg")
#: What ``phase`` takes (module docs): one phase function for every bin, by Mitsuba's names for it.
PHASE_TYPES = ("isotropic", "hg", "tabphase")
#: A procedural cloud's optics bins span its PSD's quantiles q and 1 - q (``DiscreteMedium.procedural``).
PROCEDURAL_RADIUS_QUANTILE = 1e-7
#: Most particles a procedural cloud takes (its count is a Poisson mean, not stored).
MAX_PROCEDURAL_COUNT: float = 1e15
#: Largest ``grain_depth`` (the core counts a path's scattering events in 32 bits).
MAX_GRAIN_DEPTH: int = 2**32 - 1
#: Wavelengths (um) a medium takes without a warning: 10 nm to 100 um. Beyond them a value is far more likely
#: nanometres given as micrometres (630 for 0.63) than light a renderer shows.
PLAUSIBLE_WAVELENGTH_UM = (0.01, 100.0)
DEFAULT_STORAGE = "compact"


def box_of(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi) of positions (n, 3), in the core (numpy's strided min(axis=0) takes 0.25 s a call
    at 10^7 positions)."""
    lo, hi = _motes.bounding_box(np.ascontiguousarray(pos, dtype=np.float64).ravel())
    return np.array(lo), np.array(hi)


def _bins(r: np.ndarray, size_bins: int) -> np.ndarray:
    """Log-spaced bin edges over the radii r (one bin when they are all equal)."""
    lo, hi = float(r.min()), float(r.max())
    if hi <= lo * (1 + 1e-9):
        return np.array([lo, lo])
    return np.geomspace(lo, hi, size_bins + 1)


def _checked_optics_inputs(species, wavelength_um, size_bins, scale_m):
    """The species as a list, the wavelengths as given and sorted, checked with size_bins and scale_m (what
    stored and procedural media both take)."""
    species = species_list(species)
    lam_in = np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64))
    lam = np.sort(lam_in)
    if lam.ndim != 1 or lam.size == 0 or np.any(np.diff(lam) <= 0) or np.any(~np.isfinite(lam)) or np.any(lam <= 0):
        raise ValueError(f"wavelength_um must be positive, finite and distinct, got {lam_in}")
    problem = implausible_wavelengths(lam_in, "wavelength_um")
    if problem is not None:
        warnings.warn(problem, UserWarning, stacklevel=3)
    if isinstance(size_bins, bool) or not isinstance(size_bins, (int, np.integer)) or not 1 <= size_bins <= 4096:
        raise ValueError(f"invalid size_bins = {size_bins!r}: must be an integer in [1, 4096]")
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise ValueError(f"invalid scale_m = {scale_m}: must be finite and > 0")
    return species, lam_in, lam


def implausible_wavelengths(lam_um, name: str) -> str | None:
    """What is wrong with wavelengths ``lam_um`` (um) that lie outside ``PLAUSIBLE_WAVELENGTH_UM`` (nanometres
    given as micrometres, most likely), naming ``name``; None where all are plausible. The API warns with it,
    the plugin fails loading."""
    lam = np.atleast_1d(np.asarray(lam_um, dtype=np.float64))
    lo, hi = PLAUSIBLE_WAVELENGTH_UM
    if np.all((lam >= lo) & (lam <= hi)):
        return None
    return (f"{name} = {', '.join(f'{x:g}' for x in lam)} um: outside {lo:g}-{hi:g} um (visible light is "
            f"0.38-0.78 um); in nanometres? then give {', '.join(f'{x / 1e3:g}' for x in lam)}")


def checked_grain_depth(grain_depth) -> int:
    """``grain_depth`` as an int, or a ValueError stating its range [1, ``MAX_GRAIN_DEPTH``]."""
    ok = not isinstance(grain_depth, bool) and isinstance(grain_depth, (int, np.integer))
    if not (ok and 1 <= grain_depth <= MAX_GRAIN_DEPTH):
        raise ValueError(f"invalid grain_depth = {grain_depth!r}: must be an integer in [1, {MAX_GRAIN_DEPTH}]")
    return int(grain_depth)


def species_shares(species, shares=None) -> list[float]:
    """Each species' share (``shares``, default each species' own ``share``), checked (one per species,
    finite, >= 0, one > 0) and divided by the largest: shares are relative, and 1e308 and 1e308 are an even
    split whose sum would overflow."""
    raw = [sp.share for sp in species] if shares is None else list(np.atleast_1d(shares))
    try:
        w = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"invalid share = {raw!r}: one number per species") from None
    if w.ndim != 1 or w.size != len(species) or not np.all(np.isfinite(w) & (w >= 0)) or not np.any(w > 0):
        raise ValueError(f"invalid share = {w.tolist()}: one per species ({len(species)}), finite, >= 0, "
                         "at least one > 0")
    return (w / w.max()).tolist()


def check_not_index_matched(species, eta_medium: float) -> None:
    """A ValueError for a species whose grains have the host's index (eta = eta_medium, eta_k = 0): such a
    sphere neither scatters (no index step, so no refraction and no diffraction: a_n = b_n = 0) nor absorbs,
    and a medium of it would be empty. Indices near eta_medium are taken: their weak scattering is what the
    optics compute (anomalous-diffraction-like, mostly forward)."""
    for k, sp in enumerate(species):
        if isinstance(sp.eta, Material):
            continue  # tabulated, wavelength-dependent: never one number
        eta = np.atleast_1d(np.asarray(sp.eta, dtype=np.complex128))
        if np.all((eta.real == eta_medium) & (eta.imag == 0)):
            where = f"species[{k}] " if len(species) > 1 else ""
            raise ValueError(f"{where}eta = {eta[0].real:g} equals eta_medium = {eta_medium:g} with eta_k = 0: grains "
                             "of their host's index neither scatter nor absorb (the medium would be empty); give "
                             "eta or eta_medium another value")


def check_scale(scale_m: float, r_max_um: float) -> None:
    """A ValueError naming ``scale_m`` where the largest grain (``r_max_um``) in scene units, r 1e-6 / scale_m,
    or its cross section overflows (scale_m = 1e-300)."""
    reach = r_max_um * 1e-6 / scale_m
    if not np.isfinite(np.pi * reach * reach):
        raise ValueError(f"invalid scale_m = {scale_m:g}: the largest grain ({r_max_um:g} um) would be "
                         f"{r_max_um * 1e-6 / scale_m:.3g} scene units across, beyond any finite extinction; "
                         "scale_m is metres per scene unit (1e-3: a unit is a millimetre)")


def _settings(query_radius, tau_max, cells_per_particle, continuous_count, seed=0, storage=DEFAULT_STORAGE,
              cache_bytes=None):
    """The core's ``MediumSettings`` (its own checks of each value, e.g. ``storage``, naming the parameter)."""
    return _motes.MediumSettings(query_radius=float(query_radius), tau_max=float(tau_max),
                                 cells_per_particle=float(cells_per_particle),
                                 continuous_count=float(continuous_count), seed=int(seed) & (2**64 - 1),
                                 storage=storage, cache_bytes=None if cache_bytes is None else int(cache_bytes))


def _checked_inputs(positions, radii_um, species_index, species, wavelength_um, size_bins, scale_m, settings):
    """The inputs as arrays (positions, radii, species index, species list, wavelengths as given and sorted), checked
    with the medium's ``settings`` (``_settings``)."""
    pos = np.ascontiguousarray(np.asarray(positions, dtype=np.float64))
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] == 0:
        raise ValueError(f"positions must have shape (n, 3) with n >= 1, got {pos.shape}")
    n = pos.shape[0]
    # The least any medium of n particles needs, before anything else is read (then the regime's own).
    _memory.require(_memory.BYTES_PER_PARTICLE_DENSE * n, f"a discrete medium of {n} particles")
    r = np.asarray(radii_um, dtype=np.float64).ravel()
    idx = np.asarray(species_index).ravel()
    if idx.dtype.kind not in "iu":  # kept in its integer type: an int64 copy of 1e8 indices is 800 MB
        idx = idx.astype(np.int64)
    if r.size != n or idx.size != n:
        raise ValueError(f"radii_um and species_index must have one entry per particle ({n})")
    species, lam_in, lam = _checked_optics_inputs(species, wavelength_um, size_bins, scale_m)
    if idx.size and (int(idx.min()) < 0 or int(idx.max()) >= len(species)):
        bad = int(np.flatnonzero((idx < 0) | (idx >= len(species)))[0])
        raise ValueError(f"species_index[{bad}] = {idx[bad]}: unknown species (have {len(species)})")
    # The core's own rules (cells_per_particle's range among them), checked now rather than after minutes of
    # optics tables, and before the estimate that depends on them.
    _motes.check_discrete_inputs(pos.ravel(), r, settings)
    check_scale(scale_m, float(r.max()))
    lo_box, hi_box = box_of(pos)
    extent = float(np.max(hi_box - lo_box))
    reach_max = settings.query_radius + float(r.max()) * 1e-6 / scale_m
    _memory.require_medium(n, extent, reach_max, settings.storage, settings.cells_per_particle,
                           f"a discrete medium of {n} particles")
    return pos, r, idx, species, lam_in, lam


def _bin_optics(sp: Species, lo: float, hi: float, lam, eta_medium, method, truncate_below_rad, goa_cache,
                mueller: bool = False):
    """One radius bin [lo, hi] of species ``sp``: its extinction efficiency per wavelength and its bulk
    properties (``goa_cache``: the GOA ray geometry every bin shares; ``mueller``: with its polarisation)."""
    psd = Monodisperse(lo) if hi <= lo else Uniform(lo, hi)
    area = np.pi * psd.mean(2)  # <pi r^2>, um^2
    extra = {"mueller": True} if mueller else {}
    bulk = bulk_properties(Species(psd, sp.eta), 1.0, lam, eta_medium, method, truncate_below_rad=truncate_below_rad,
                           goa_cache=goa_cache, **extra)
    # n = 1 / m^3: sigma (1/m) is the mean cross section in m^2.
    return bulk["sigma_t"] * 1e12 / area, bulk


class _BinTables:
    """The optics bins of a medium as they are added (one ``add`` per radius bin of a species): each bin's
    grey Q_ext, albedo per wavelength and phase tables, and what the medium reports about them."""

    def __init__(self, lam, rank, eta_medium, method, truncate_below_rad, albedo, phase_model="tabulated", phase=None,
                 polarized=False):
        if phase_model not in PHASE_MODELS:
            raise ValueError(f"invalid phase_model = {phase_model!r}: must be one of {', '.join(PHASE_MODELS)}")
        if phase is not None and phase_model != "tabulated":
            raise ValueError(f"phase_model = {phase_model!r} and phase = {phase!r} both replace the grains' phase "
                             "function: give one")
        self.lam, self.rank, self.eta_medium, self.method = lam, rank, eta_medium, method
        self.phase_model = phase_model
        #: The user's phase function for every bin (``phase_table``), or None: the grains' own.
        self.phase = None if phase is None else phase_table(phase)
        #: Polarised variants: the grains' Mueller ratios beside their phase tables, where the phase function is
        #: theirs (a user's phase function and Henyey-Greenstein depolarise, as Mitsuba's own do).
        self.polarized = bool(polarized) and phase is None and phase_model == "tabulated"
        self.mueller = []
        self.truncate_below_rad = truncate_below_rad
        self.albedo = _checked_albedo(albedo, rank.size)
        if self.albedo is not None and self.albedo.ndim == 1:  # per channel -> per tabulated wavelength
            by_rank = np.empty(lam.size)
            by_rank[rank] = self.albedo
            self.albedo = by_rank
        self.grey_q, self.albedos, self.theta, self.f, self.offsets = [], [], [], [], [0]
        self.radius_um, self.species, self.q_ext, self.bin_albedo, self.bin_g = [], [], [], [], []
        self.goa_cache = _motes.GoaCache()  # shared by this medium's bins, dropped after the build
        self.t_start = self.t_said = time.perf_counter()

    def add(self, k: int, sp: Species, lo: float, hi: float) -> int:
        """The bin [lo, hi] um of species ``k``; returns its global index."""
        q_t, bulk = _bin_optics(sp, lo, hi, self.lam, self.eta_medium, self.method, self.truncate_below_rad,
                                self.goa_cache, self.polarized)
        self.grey_q.append(float(np.mean(q_t)))
        if self.albedo is None:
            self.albedos.append(np.clip(bulk["albedo"], 0.0, 1.0))
        elif self.albedo.ndim == 0:
            self.albedos.append(np.full(self.lam.size, float(self.albedo)))
        else:
            self.albedos.append(self.albedo.copy())
        g = []
        for i, row in enumerate(bulk["phase"]):
            theta = bulk["theta"]
            if self.phase_model == "hg":  # the same g (of the truncated table the render would use)
                row = _motes.henyey_greenstein(_motes.PhaseTable(bulk["theta"], row).mean_cosine(), bulk["theta"])
            elif self.phase is not None:  # the user's, the same in every bin and channel
                theta, row = self.phase(bulk["theta"])
            self.theta.append(theta)
            self.f.append(row)
            if self.polarized:  # (r12, r33, r34) rows on theta, as the core's BinTables take them
                self.mueller.append(np.asarray(bulk["mueller"][i], dtype=np.float64).ravel())
            self.offsets.append(self.offsets[-1] + theta.size)
            g.append(_motes.PhaseTable(theta, row).mean_cosine())
        self.radius_um.append((lo, hi))
        self.species.append(k)
        self.q_ext.append(q_t[self.rank])
        self.bin_albedo.append(bulk["albedo"][self.rank])
        self.bin_g.append(np.asarray(g)[self.rank])
        if time.perf_counter() - self.t_said > 1.0:  # long builds say where they are, once a second
            self.t_said = time.perf_counter()
            log.info("optics tables: %d bins so far (species %d), %.1f s", len(self.grey_q), k,
                     self.t_said - self.t_start)
        return len(self.grey_q) - 1

    def report(self, medium) -> None:
        """The bins' figures as the medium's attributes."""
        log.info("optics tables: %d bins in %.1f s", len(self.grey_q), time.perf_counter() - self.t_start)
        medium.bin_radius_um, medium.bin_species = self.radius_um, self.species
        medium.bin_q_ext, medium.bin_albedo, medium.bin_g = self.q_ext, self.bin_albedo, self.bin_g
        medium.n_bins = len(self.grey_q)

    def core_tables(self):
        """(albedos, theta, f, offsets, mueller or None) as the core's constructors take them."""
        return self.albedos, self.theta, self.f, self.offsets, (self.mueller if self.polarized else None)


def _checked_albedo(albedo, channels: int):
    """``albedo`` as None, a 0-d array (every channel) or one value per channel, each in [0, 1]."""
    if albedo is None:
        return None
    a = np.asarray(albedo, dtype=np.float64)
    if a.ndim > 1 or (a.ndim == 1 and a.size != channels):
        raise ValueError(f"invalid albedo = {albedo!r}: one number, or one per wavelength ({channels})")
    if not np.all(np.isfinite(a) & (a >= 0) & (a <= 1)):
        raise ValueError(f"invalid albedo = {albedo}: must be in [0, 1]")
    return a


def phase_table(phase: dict):
    """The ``phase`` a medium renders every bin with (module docs), as a function of a bin's angle grid
    theta (radians, 0 to pi) returning that bin's (theta, f): isotropic and Henyey-Greenstein on the bin's
    grid, a ``tabphase`` on its own nodes (piecewise linear in cos(theta), as Mitsuba's ``tabphase`` and
    the core's tables both are: the same function), normalised to 1 over the sphere."""
    if not isinstance(phase, dict) or phase.get("type") not in PHASE_TYPES:
        raise ValueError(f"invalid phase = {phase!r}: a dict whose \"type\" is one of {', '.join(PHASE_TYPES)}")
    kind = phase["type"]
    extra = sorted(set(phase) - {"type"} - {"hg": {"g"}, "tabphase": {"values"}, "isotropic": set()}[kind])
    if extra:
        raise ValueError(f"invalid phase = {phase!r}: a {kind} phase function takes no {', '.join(extra)}")
    if kind == "isotropic":
        return lambda theta: (theta, np.full(theta.size, 0.25 / np.pi))
    if kind == "hg":
        g = phase.get("g")
        if isinstance(g, bool) or not isinstance(g, (int, float, np.floating)) or not -1 < g < 1:
            raise ValueError(f"invalid hg phase function g = {g!r}: must be in (-1, 1)")
        return lambda theta: (theta, _motes.henyey_greenstein(float(g), theta))
    values = np.asarray(phase.get("values", ()), dtype=np.float64).ravel()
    if values.size < 2 or not np.all(np.isfinite(values) & (values >= 0)) or not np.any(values > 0):
        raise ValueError(f"invalid tabphase values = {phase.get('values')!r}: at least two, finite, >= 0, "
                         "not all zero")
    mu = np.linspace(-1.0, 1.0, values.size)
    # Increasing theta: forward (mu = 1) first. Normalised as Mitsuba's tabphase: 2 pi int f dmu = 1.
    theta = np.ascontiguousarray(np.arccos(mu[::-1]))
    theta[0], theta[-1] = 0.0, np.pi
    f = values[::-1] / (2.0 * np.pi * np.trapezoid(values, mu))
    return lambda _theta: (theta, np.ascontiguousarray(f))


def mean_extinction_um2(species, wavelength_um, *, shares=None, size_bins: int = 16, eta_medium: float = 1.0,
                        method: str = "auto", truncate_below_rad: float | None = DEFAULT_TRUNCATE_RAD) -> float:
    """The grains' mean grey extinction cross section <C_ext> (um^2) over their PSDs (species mixed by
    ``shares``, default each species' ``share``), exactly as a medium of these arguments gives each grain
    its own: its optics bin's grey Q_ext (the mean over the wavelengths, forward peak truncated below
    ``truncate_below_rad``) times pi r^2. The bins are ``size_bins`` per species, log-spaced between the
    PSD's quantiles 1e-7 and 1 - 1e-7 (the rarer radii beyond in the end bins): a procedural cloud's bins
    (``DiscreteMedium.procedural``); a stored cloud spans its own grains' radii, which moves the mean by
    what a bin's Q_ext varies across the PSD's far tails. A bulk extinction sigma_t (1/m) is then
    n <C_ext> 1e-12 with n grains per m^3."""
    species, lam_in, lam = _checked_optics_inputs(species, wavelength_um, size_bins, 1.0)
    w = np.asarray(species_shares(species, shares))
    check_not_index_matched(species, eta_medium)
    if truncate_below_rad is not None and truncate_below_rad <= 0:
        truncate_below_rad = None
    tables = _BinTables(lam, np.searchsorted(lam, lam_in), eta_medium, method, truncate_below_rad, None)
    edges_all, first = _procedural_bins(tables, species, int(size_bins))
    grey_q = np.asarray(tables.grey_q)
    total = 0.0
    for k, sp in enumerate(species):
        r, wr = sp.psd.quadrature(0.01)
        edges = np.asarray(edges_all[k])
        which = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, max(edges.size - 2, 0))
        total += w[k] * float(np.sum(wr * np.pi * r**2 * grey_q[first[k] + which]) / np.sum(wr))
    return total / float(w.sum())


def _core_tables(tables, lam) -> _motes.BinTables:
    """The core's ``BinTables`` of (albedos, theta, f, offsets) per bin and the tabulated wavelengths (um)."""
    albedos, theta, f, offsets, mueller = tables
    return _motes.BinTables(np.ascontiguousarray(np.concatenate(albedos)), np.ascontiguousarray(np.concatenate(theta)),
                            np.ascontiguousarray(np.concatenate(f)), np.asarray(offsets, dtype=np.uint64),
                            np.ascontiguousarray(lam * 1e3),
                            None if mueller is None else np.ascontiguousarray(np.concatenate(mueller)))


def _camera_tuple(position, pixel_angle, aperture, axis=(0.0, 0.0, 0.0), pixel_width=0.0) -> tuple:
    """A camera for the core: (position, pixel angle, aperture, orthographic axis, orthographic pixel width) as
    floats (``DiscreteMedium.set_cameras``)."""
    p, a = (tuple(float(v[i]) for i in range(3)) for v in (position, axis))
    return p, float(pixel_angle), float(aperture), a, float(pixel_width)


def _light_tuple(centre, radius, disc=0.0, normal=(0.0, 0.0, 0.0), axis=(0.0, 0.0, 0.0), cos_cutoff=-1.0) -> tuple:
    """A light for the core: (centre, radius, disc, normal, spot axis, spot cos_cutoff) as floats
    (``DiscreteMedium.set_cameras``)."""
    c, n, a = (tuple(float(v[i]) for i in range(3)) for v in (centre, normal, axis))
    return c, float(radius), float(disc), n, a, float(cos_cutoff)


def _procedural_bins(tables: _BinTables, species: list, size_bins: int) -> tuple[list, list]:
    """Each species' ``size_bins`` log-spaced optics bins of a procedural cloud, added to ``tables``: (the bin
    edges of each species, the index of each species' first bin)."""
    edges_all, first = [], []
    for k, sp in enumerate(species):
        # Over the radii a cloud of this size holds (as a stored cloud's bins span its particles'
        # radii): quantiles 1e-7 and 1 - 1e-7 (+-5.2 sigma of a log-normal); the rare radii beyond
        # belong to the end bins. Bins over a truncated PSD's whole support were 1.5 times wider in
        # ln r and their mean Q_ext moved a stored cloud's transmittance by 2 % (10 SE).
        r_lo, r_hi = (float(v) for v in sp.psd.quantile(np.array([PROCEDURAL_RADIUS_QUANTILE,
                                                                  1.0 - PROCEDURAL_RADIUS_QUANTILE])))
        edges = np.geomspace(r_lo, r_hi, size_bins + 1) if r_hi > r_lo * (1 + 1e-9) else np.array([r_lo, r_lo])
        first.append(len(tables.grey_q))
        for b in range(edges.size - 1):
            tables.add(k, sp, float(edges[b]), float(edges[b + 1]))
        edges_all.append([float(e) for e in edges])
    return edges_all, first


class DiscreteMedium:
    """Particles with per-bin optics in the Rust medium (module docs)."""

    def __init__(self, positions, radii_um, species_index, species, wavelength_um, *, scale_m: float = 1.0,
                 query_radius: float = 0.0, size_bins: int = 16, eta_medium: float = 1.0, method: str = "auto",
                 truncate_below_rad: float | None = DEFAULT_TRUNCATE_RAD, cells_per_particle: float = DEFAULT_CELLS_PER_PARTICLE, seed: int = 0,
                 albedo: float | None = None, tau_max: float = DEFAULT_TAU_MAX, warn_widened: bool = False,
                 continuous_count: float = DEFAULT_CONTINUOUS_COUNT, grain_depth: int = DEFAULT_GRAIN_DEPTH,
                 storage: str = DEFAULT_STORAGE, phase_model: str = "tabulated", surface_footprint: bool = True,
                 phase: dict | None = None, holders=None, density=None, polarized: bool = False):
        self.storage = storage  # checked by the core (``Storage::parse``: a MotesError naming it)
        grain_depth = checked_grain_depth(grain_depth)
        settings = _settings(query_radius, tau_max, cells_per_particle, continuous_count, seed, storage)
        pos, r, idx, species, lam_in, lam = _checked_inputs(
            positions, radii_um, species_index, species, wavelength_um, size_bins, scale_m, settings)
        check_not_index_matched(species, eta_medium)
        if truncate_below_rad is not None and truncate_below_rad <= 0:
            truncate_below_rad = None

        _checked_albedo(albedo, lam.size)
        rank = np.searchsorted(lam, lam_in)  # channel c is tabulated wavelength rank[c]
        bin_of, grey_q, tables = self._optics_tables(r, idx, species, lam, rank, int(size_bins), eta_medium, method,
                                                    truncate_below_rad, albedo, phase_model, phase, polarized)
        self._build_core(pos, r, idx, lam_in, lam, bin_of, grey_q, tables, scale_m, settings, warn_widened, holders,
                         density)
        self._set_path_rules(grain_depth, surface_footprint)

    def _set_path_rules(self, grain_depth: int, surface_footprint: bool) -> None:
        """Which rays see the grains' continuous equivalent (module docs: ``grain_depth``, ``surface_footprint``)."""
        if not isinstance(surface_footprint, (bool, np.bool_)):
            raise ValueError(f"invalid surface_footprint = {surface_footprint!r}: must be True or False")
        self._core.set_grain_depth(int(grain_depth))
        self._core.set_surface_footprint(bool(surface_footprint))
        #: See the module docs.
        self.grain_depth = int(grain_depth)
        self.surface_footprint = bool(surface_footprint)

    def set_cameras(self, cameras, lights=None, diffuse_surfaces=False, samples_per_pixel=0) -> None:
        """The cameras whose pixel footprints camera rays and rays from surfaces carry (``surface_footprint``): a
        list of (position (x, y, z) in scene units, narrowest angular pixel width in radians, lens aperture radius)
        for a pinhole or thin-lens camera, or (position, 0, 0, axis (x, y, z), pixel width in scene units) for an
        orthographic one; empty: every ray walks the grains. ``lights``: the lights at finite distance that shadow
        rays converge to, a list of (centre (x, y, z), radius) (0 for a point or spot light) or (centre, radius,
        disc, normal) or (centre, radius, disc, normal, axis, cos_cutoff): a disc of radius ``disc`` <= ``radius``
        around the centre that lies on the light, with its normal (x, y, z), or (0, 0, 0) where the light shows
        the whole disc from every side (a sphere): an area light's penumbra blurs the grains' shadows; a spot's
        axis and the cosine of its cutoff angle (a shadow ray from outside its cone carries nothing: it sees the
        continuous equivalent; axis (0, 0, 0) and -1: no spot); None: unknown, every ray taken to end at a light
        (safe, and the rule then rarely applies). ``diffuse_surfaces``: every surface of the scene reflects and
        transmits only diffusely, so that a ray bounced off one carries the grains blurred by the lobe (default
        False: a surface may be a mirror). ``samples_per_pixel``: the render's, which sets how many grains a camera
        ray's pixel must hold to see their continuous equivalent (0: unknown, camera rays walk the grains).
        ``motes.plugins.cameras`` sets all four from a Mitsuba scene before every render."""
        try:
            cams = [_camera_tuple(*c) for c in cameras]
        except (TypeError, ValueError, IndexError):
            raise ValueError("cameras must be a list of ((x, y, z), pixel_angle, aperture) or ((x, y, z), 0, 0, "
                             "(ax, ay, az), pixel_width) tuples") from None
        spp = float(samples_per_pixel)
        if not (np.isfinite(spp) and spp >= 0):
            raise ValueError(f"invalid samples_per_pixel = {samples_per_pixel!r}: must be finite and >= 0")
        if lights is not None:
            try:
                lights = [_light_tuple(*light) for light in lights]
            except (TypeError, ValueError, IndexError):
                raise ValueError("lights must be None or a list of ((x, y, z), radius), ((x, y, z), radius, disc, "
                                 "(nx, ny, nz)) or (..., (ax, ay, az), cos_cutoff) tuples") from None
        self._core.set_cameras(cams, lights, bool(diffuse_surfaces), spp)

    def set_enclosure(self, meshes=(), balls=()) -> int:
        """The convex shapes that hold the medium, inside which no surface lets a shadow ray through: ``meshes`` as
        (vertices (n, 3), faces (m, 3)) pairs, ``balls`` as ((x, y, z), radius) pairs, in scene units. A phase
        evaluation towards the direction of a path's last free flight, from its origin, is then zero where that flight
        ended at a site inside the region holding its origin: next-event estimation multiplies it by the light the
        blocked shadow ray does not see (Mitsuba's ``volpath`` and ``volpathmis``; ``motes.plugins.enclosure`` sets
        this only for them). Open or non-convex meshes hold nothing. Returns the number of regions set; no arguments:
        none (every evaluation computed, the default)."""
        try:
            mesh_arrays = [(np.ascontiguousarray(v, dtype=np.float64).reshape(-1),
                            np.ascontiguousarray(f, dtype=np.uint32).reshape(-1)) for v, f in meshes]
            ball_tuples = [((float(c[0]), float(c[1]), float(c[2])), float(r)) for c, r in balls]
        except (TypeError, ValueError, IndexError):
            raise ValueError("meshes must be (vertices (n, 3), faces (m, 3)) pairs and balls ((x, y, z), radius) "
                             "pairs") from None
        return self._core.set_enclosure(mesh_arrays, ball_tuples)

    @property
    def enclosure_regions(self) -> int:
        """The number of convex regions set by ``set_enclosure``."""
        return self._core.enclosure_regions

    @property
    def diffuse_surfaces(self) -> bool:
        """Whether the scene's surfaces were set as diffuse only (``set_cameras``)."""
        return self._core.diffuse_surfaces

    @property
    def samples_per_pixel(self) -> float:
        """The render's samples per pixel as ``set_cameras`` last set them (0: unknown)."""
        return self._core.samples_per_pixel

    @property
    def cameras(self) -> list:
        """The cameras set by ``set_cameras``."""
        return self._core.cameras

    @property
    def lights(self) -> list | None:
        """The lights set by ``set_cameras`` (None: unknown)."""
        return self._core.lights

    def _optics_tables(self, r, idx, species, lam, rank, size_bins, eta_medium, method, truncate_below_rad, albedo,
                       phase_model, phase=None, polarized=False):
        """Each particle's optics bin and grey Q_ext, and the per-bin tables the core takes (albedos, theta, f, offsets)."""
        n = r.size
        bin_of = np.zeros(n, dtype=np.uint32)
        tables = _BinTables(lam, rank, eta_medium, method, truncate_below_rad, albedo, phase_model, phase, polarized)
        for k, sp in enumerate(species):
            # One species (the common case): every particle, without index arrays (1e8 particles).
            sel = slice(None) if len(species) == 1 else np.flatnonzero(idx == k)
            rs = r[sel]
            if rs.size == 0:
                continue
            edges = _bins(rs, size_bins)
            # searchsorted(edges, rs, "right") - 1, clipped to the bins, in parallel (numpy's one thread
            # took ~20 s at 1e8 particles for this and the gather below).
            which = _motes.size_bins(rs, edges)
            global_bin = np.zeros(max(edges.size - 1, 1), dtype=np.uint32)
            for b in np.flatnonzero(np.bincount(which, minlength=global_bin.size)):
                global_bin[b] = tables.add(k, sp, float(edges[b]), float(edges[b + 1]))
            del which
            if len(species) == 1:
                bin_of = _motes.size_bins(rs, edges, global_bin)
            else:
                bin_of[sel] = _motes.size_bins(rs, edges, global_bin)
            del rs
        tables.report(self)
        return bin_of, np.asarray(tables.grey_q), tables.core_tables()

    def _build_core(self, pos, r, idx, lam_in, lam, bin_of, grey_q, tables, scale_m, settings, warn_widened,
                    holders=None, density=None):
        """The Rust medium over the particles and their bins' tables, and the attributes that report it."""
        n = pos.shape[0]
        query_radius, tau_max = settings.query_radius, settings.tau_max
        t_grid = time.perf_counter()
        um = 1e-6 / scale_m
        # Each particle's cross section is pi r^2 of its bin's grey Q_ext: the core computes it (a column of
        # 1e8 particles is 800 MB); the Python layer forms it only to report it (full storage) or to warn.
        c_ext_of = lambda: np.pi * (r * um) ** 2 * grey_q[bin_of]  # noqa: E731
        self.scale_m = float(scale_m)
        self.query_radius = float(query_radius)
        self.wavelength_um = lam
        #: The wavelengths as given (for RGB: channel c is ``channel_wavelength_nm[c]``).
        self.channel_wavelength_nm = np.ascontiguousarray(lam_in * 1e3)
        # Radii in um with their scale (a scaled copy of 1e8 radii would be 800 MB).
        #: The optics bins' tables as the core took them: (albedos, theta, f, offsets, mueller or None) per bin
        #: (``_BinTables.core_tables``), at ``wavelength_um``; read by ``kernel = "drjit"`` (``plugins/drjit_medium.py``).
        self.bin_tables = tables
        self._core = _motes.DiscreteMedium(pos.ravel(), r, np.ascontiguousarray(grey_q, dtype=np.float64), bin_of,
                                           _core_tables(tables, lam), settings, radius_scale=um, holders=holders,
                                           density=density)
        log.info("grid: %d particles, %.1f MB, %.1f s", n, self._core.bytes / 1e6, time.perf_counter() - t_grid)
        #: Particles whose disk the tau_max cap widened beyond query_radius + r_i.
        self.widened = self._core.widened
        self.tau_max = float(tau_max)
        #: Particles sampled as a continuous medium (``continuous_count``).
        self.continuous_particles = self._core.continuous_particles
        if warn_widened and self.widened > WIDENED_WARN_SHARE * n:
            frac = float(np.max(c_ext_of() / (np.pi * (query_radius + r * um) ** 2)))
            tau = -np.log1p(-frac) if frac < 1 else np.inf
            # stacklevel 3: the caller of DiscreteMedium(...), past this method and __init__.
            warnings.warn(f"query_radius = {query_radius:g} would give {self.widened} of {n} particles an optical "
                          f"depth above tau_max = {tau_max:g} (up to {tau:.3g}); their disks were widened to keep it "
                          "below (see the tau_max parameter)", stacklevel=3)
        lo_, hi_ = box_of(pos)
        # Per-particle arrays only where the user asked for full storage (at 1e8 particles they are 5 GB).
        full = self.storage == "full"
        self.positions = pos if full else None
        self.species_index = idx if full else None
        #: Each particle's optics bin (index into bin_radius_um, bin_q_ext, bin_albedo); full storage only.
        self.particle_bin = bin_of if full else None
        self.radii_um = r if full else None
        self.c_ext_scene = c_ext_of() if full else None
        #: The box of the particles' centres (scene units).
        self.centre_box = (lo_, hi_)
        reach = float(self._core.reach_max)
        self.bbox = (lo_ - reach, hi_ + reach)

    @classmethod
    def procedural(cls, count: float, species, shares, wavelength_um, *, box=((-1.0,) * 3, (1.0,) * 3),
                   density: tuple = ("uniform", []), noise_seed: int = 0, cloud_seed: int = 0, to_world=None,
                   scale_m: float = 1.0, query_radius: float = 0.0, size_bins: int = 16, eta_medium: float = 1.0,
                   method: str = "auto", truncate_below_rad: float | None = DEFAULT_TRUNCATE_RAD,
                   cells_per_particle: float = DEFAULT_CELLS_PER_PARTICLE, seed: int = 0,
                   albedo: float | None = None, tau_max: float = DEFAULT_TAU_MAX,
                   continuous_count: float = DEFAULT_CONTINUOUS_COUNT, grain_depth: int = DEFAULT_GRAIN_DEPTH,
                   cache_bytes: int | None = None, phase_model: str = "tabulated", turbulence: float = 0.0,
                   turbulence_scale: float = 1.0, time_s: float = 0.0,
                   surface_footprint: bool = True, phase: dict | None = None,
                   polarized: bool = False) -> "DiscreteMedium":
        """A procedural cloud (``storage = "procedural"``; ``rust/motes-core/src/render/procedural/``):
        ``count`` expected particles in ``box`` (the cloud's own coordinates, mapped by the 4x4
        ``to_world``) after ``density`` = (kind, params) as ``_motes.generate_cloud`` takes it, species by
        ``shares``; no particle is stored: each brick of the cloud is generated from ``cloud_seed`` when a
        ray first needs it and kept in a cache of at most ``cache_bytes`` (default: a quarter of the memory
        available, ``motes._memory.default_cache_bytes``; the least recently used bricks are dropped beyond
        it and generated again when a ray needs them). ``turbulence`` (scene units), ``turbulence_scale``
        and ``time_s`` (seconds) move the discrete grains by the divergence-free drift of
        ``rust/motes-core/src/space/motion.rs`` (a velocity is a shift of ``to_world``). The other parameters
        as the constructor's; each species' ``size_bins`` optics bins are log-spaced over its PSD's support."""
        self = cls.__new__(cls)
        self.storage = "procedural"
        grain_depth = checked_grain_depth(grain_depth)
        if not (np.isfinite(count) and 1 <= count <= MAX_PROCEDURAL_COUNT):
            raise ValueError(f"invalid count = {count!r}: a procedural cloud takes 1 to {MAX_PROCEDURAL_COUNT:g} particles")
        species, lam_in, lam = _checked_optics_inputs(species, wavelength_um, size_bins, scale_m)
        shares = species_shares(species, shares)
        check_not_index_matched(species, eta_medium)
        check_scale(scale_m, max(float(sp.psd.quantile(np.array([1.0 - PROCEDURAL_RADIUS_QUANTILE]))[0])
                                 for sp in species))
        if cache_bytes is None:
            cache_bytes = _memory.default_cache_bytes()
        if isinstance(cache_bytes, bool) or not isinstance(cache_bytes, (int, np.integer)) or cache_bytes < 1:
            raise ValueError(f"invalid cache_bytes = {cache_bytes!r}: must be a positive integer")
        if truncate_below_rad is not None and truncate_below_rad <= 0:
            truncate_below_rad = None
        _checked_albedo(albedo, lam.size)
        m = np.eye(4) if to_world is None else np.asarray(to_world, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise ValueError(f"to_world must be a finite 4x4 matrix, got shape {m.shape}")
        lo, hi = (np.asarray(v, dtype=np.float64).reshape(3) for v in box)
        rank = np.searchsorted(lam, lam_in)
        tables = _BinTables(lam, rank, eta_medium, method, truncate_below_rad, albedo, phase_model, phase, polarized)
        edges_all, first = _procedural_bins(tables, species, size_bins)
        tables.report(self)
        kind, params = density
        t_build = time.perf_counter()
        self._core = _motes.DiscreteMedium.procedural(
            float(count), (lo.tolist(), hi.tolist()), (kind, [float(x) for x in params], int(noise_seed) & (2**64 - 1)),
            ([sp.psd._core for sp in species], shares), int(cloud_seed) & (2**64 - 1), m[:3, :4].tolist(),
            1e-6 / float(scale_m), (edges_all, first, [float(q) for q in tables.grey_q]),
            _core_tables(tables.core_tables(), lam),
            _settings(query_radius, tau_max, cells_per_particle, continuous_count, seed, cache_bytes=cache_bytes),
            turbulence=float(turbulence), turbulence_scale=float(turbulence_scale), time=float(time_s))
        log.info("procedural cloud: %.3g particles, %.3g of them continuous, %.1f MB before any brick, %.1f s",
                 count, self._core.continuous_particles, self._core.bytes / 1e6, time.perf_counter() - t_build)
        self._set_path_rules(grain_depth, surface_footprint)
        self.scale_m, self.query_radius, self.wavelength_um = float(scale_m), float(query_radius), lam
        self.channel_wavelength_nm = np.ascontiguousarray(lam_in * 1e3)
        self.widened, self.tau_max = self._core.widened, float(tau_max)
        self.continuous_particles = self._core.continuous_particles
        self.positions = self.species_index = self.particle_bin = self.radii_um = self.c_ext_scene = None
        corners = np.array([[hi[a] if (i >> a) & 1 else lo[a] for a in range(3)] for i in range(8)]) @ m[:3, :3].T + m[:3, 3]
        lo_, hi_ = corners.min(axis=0), corners.max(axis=0)
        self.centre_box = (lo_, hi_)
        reach = float(self._core.reach_max)
        self.bbox = (lo_ - reach, hi_ + reach)
        return self

    def __len__(self) -> int:
        return len(self._core)

    def summary(self) -> str:
        """What the ``discrete`` plugin's ``str()`` reports (both render paths)."""
        return (f"DiscreteMedium[particles={len(self)}, bins={self.n_bins}, query_radius={self.query_radius:g}, "
                f"scale_m={self.scale_m:g}, bytes={self.bytes}]")

    @property
    def core(self):
        """The Rust medium (``motes._motes.DiscreteMedium``)."""
        return self._core

    @property
    def bytes(self) -> int:
        return self._core.bytes

    def _channels(self, wavelength_um):
        lam = self.channel_wavelength_nm if wavelength_um is None else np.atleast_1d(np.asarray(wavelength_um, dtype=np.float64)) * 1e3
        if lam.ndim != 1 or lam.size == 0 or not np.all(np.isfinite(lam) & (lam > 0)):
            raise ValueError("wavelength_um must be positive and finite")
        return np.ascontiguousarray(lam), lam.size

    def local_scattering(self, points, cos_theta, wavelength_um=None):
        """Eq. 24 at points: the particles whose inclusion ball (r_c + r_i) holds the point each add
        C_s / (4/3 pi R^3). Returns (sigma_s, Q) of shape (n, channels): sigma_s per scene unit and
        Q = sigma_s f(theta) at ``cos_theta`` (1/sr per unit). Channels: the tabulated wavelengths in
        the order given at construction, or ``wavelength_um``."""
        p = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must have shape (n, 3), got {p.shape}")
        mu = np.ascontiguousarray(np.broadcast_to(np.asarray(cos_theta, dtype=np.float64), (p.shape[0],)))
        if not np.all(np.abs(mu) <= 1):
            raise ValueError("cos_theta must be in [-1, 1]")
        lam, ch = self._channels(wavelength_um)
        s, q = self._core.local_scattering(p.ravel(), mu, lam, ch)
        return s.reshape(-1, ch), q.reshape(-1, ch)

    def sample_local(self, points, directions, u1, u2, wavelength_um=None):
        """Scattered directions from the local particle mixture at points (a particle with probability
        proportional to its local scattering weight, then its tabulated phase function): (wo (n, 3),
        weight = f_c / pdf (n, channels), pdf (n,), 1/sr); pdf = 0 where no particle is local.
        ``directions`` are propagation directions, ``u1`` (n,) and ``u2`` (n, 2) uniform in [0, 1)."""
        p = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
        n = p.shape[0]
        d = np.ascontiguousarray(np.broadcast_to(np.asarray(directions, dtype=np.float64), (n, 3)))
        a = np.ascontiguousarray(np.broadcast_to(np.asarray(u1, dtype=np.float64), (n,)))
        b = np.ascontiguousarray(np.broadcast_to(np.asarray(u2, dtype=np.float64), (n, 2)))
        lam, ch = self._channels(wavelength_um)
        wo, w, pdf = self._core.sample_local(p.ravel(), d.ravel(), lam, ch, a, b.ravel())
        return wo.reshape(n, 3), w.reshape(n, ch), pdf

    def optical_depth(self, origins, directions, t0, t1) -> np.ndarray:
        """Grey optical depth of segments (as the renderer's free flights see it)."""
        o = np.ascontiguousarray(np.atleast_2d(np.asarray(origins, dtype=np.float64)))
        d = np.ascontiguousarray(np.atleast_2d(np.asarray(directions, dtype=np.float64)))
        o, d = np.broadcast_arrays(o, d)
        m = o.shape[0]
        a = np.ascontiguousarray(np.broadcast_to(np.asarray(t0, dtype=np.float64), (m,)))
        b = np.ascontiguousarray(np.broadcast_to(np.asarray(t1, dtype=np.float64), (m,)))
        return self._core.optical_depth((np.ascontiguousarray(o).ravel(), np.ascontiguousarray(d).ravel(), a, b))


__all__ = ["DiscreteMedium", "mean_extinction_um2", "phase_table"]
