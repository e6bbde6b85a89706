"""motes: discrete participating media for Mitsuba 3, over a Rust core.

Single-particle optics
----------------------
All lengths are in micrometres and angles in radians. ``eta`` is the particle's complex refractive
index ``n + i*kappa`` (``kappa >= 0`` absorbs; a float means ``kappa = 0``), ``eta_medium`` the host's
real index, so the relative index is ``eta / eta_medium`` and the size parameter
``alpha = 2*pi*eta_medium*radius_um/wavelength_um``. Every argument broadcasts like numpy.

==========================  ==================================================================
``mie_amplitudes``          Lorenz-Mie S1, S2 (Bohren-Huffman convention, ``C_ext = 4pi/k^2 Re S(0)``)
``goa_amplitudes``          Geometrical-optics S1, S2: diffraction + ray orders p = 0..p_max
``cross_sections``          dict of ``ext``, ``sca``, ``abs`` (um^2) and ``g``
``phase_function``          f_p(theta) of Eq. 1, normalised so that the integral over the sphere is 1
``mueller_matrix``          F11, F12, F33, F34 (Bohren-Huffman), F11 = ``phase_function``
``size_parameter``          alpha for given radius, wavelength and host index
``resolve_method``          which theory ("mie"/"goa") a method picks for each particle
``clear_goa_cache``         free the GOA ray geometry these functions keep between calls
==========================  ==================================================================

Beyond single particles
-----------------------
==========================  ==================================================================
``bulk_properties``         ensembles of particles (Eq. 16-17), ``motes.ensemble``
``homogeneous_equivalent``  Mitsuba ``homogeneous`` + ``tabphase`` of an ensemble, ``motes.equivalent``
``ParticleGrid``            particles in a grid: optical depth (Eq. 18), exact free flights
``density_box``             particle positions from a density field; ``uniform_box``
``DiscreteMedium``          the renderer's view: sites, Eq. 24 at points, local-mixture sampling
``set_variant``             Mitsuba variant + the ``discrete`` medium and ``particle`` phase plugins
==========================  ==================================================================

Particle size distributions: ``motes.psd`` (``LogNormal``, ``Monodisperse``, ``Uniform``, ``Histogram``,
``Mixture``), exported at the top level too.

``method`` selects the theory: ``"mie"`` (exact), ``"goa"``, ``"hybrid"`` (Mie below
``hybrid_radius_um``, default the paper's 2 um) or ``"auto"`` (Mie below the size parameter
``AUTO_SIZE_PARAMETER``, chosen from measured GOA error, and near the degenerate axial rays of
``AXIAL_CAUSTIC_WINDOW`` such as eta = 2; see BENCHMARKS.md).
"""

from __future__ import annotations

from .plugins import configure_llvm as _configure_llvm

_configure_llvm()  # before Dr.Jit loads (a no-op when DRJIT_LIBLLVM_PATH is set or no libLLVM 19 exists)

from . import psd  # noqa: E402
from ._motes import MotesError  # noqa: E402  (a ValueError with .argument and .value)
from .particle_io import ParticleSet, load_particles, save_particles
from .particles import Gradient, Noise, ParticleGrid, density_box, extinction_um2, nearest_depth, query_radius_from_camera, uniform_box
from .equivalent import homogeneous_equivalent
from .ensemble import CORE_HASH, DEFAULT_TRUNCATE_RAD, RGB_WAVELENGTHS_UM, SPECTRAL_WAVELENGTHS_UM, Material, PhaseTable, SpectralTable, Species, bulk_properties, pixel_footprint_rad
from .psd import Histogram, LogNormal, Mixture, Monodisperse, Radii, Uniform
from ._optics import (
    AUTO_SIZE_PARAMETER,
    AXIAL_CAUSTIC_WINDOW,
    HYBRID_RADIUS_UM,
    clear_goa_cache,
    cross_sections,
    goa_amplitudes,
    goa_cache_info,
    goa_extinction_efficiency,
    mie_amplitudes,
    mueller_matrix,
    phase_function,
    resolve_method,
    size_parameter,
)

__all__ = [
    "psd",
    "ParticleGrid",
    "ParticleSet",
    "load_particles",
    "save_particles",
    "extinction_um2",
    "uniform_box",
    "density_box",
    "Gradient",
    "Noise",
    "query_radius_from_camera",
    "nearest_depth",
    "CORE_HASH",
    "Material",
    "PhaseTable",
    "SpectralTable",
    "Species",
    "bulk_properties",
    "pixel_footprint_rad",
    "homogeneous_equivalent",
    "RGB_WAVELENGTHS_UM",
    "SPECTRAL_WAVELENGTHS_UM",
    "Histogram",
    "LogNormal",
    "Mixture",
    "Monodisperse",
    "Radii",
    "Uniform",
    "AUTO_SIZE_PARAMETER",
    "AXIAL_CAUSTIC_WINDOW",
    "HYBRID_RADIUS_UM",
    "clear_goa_cache",
    "cross_sections",
    "goa_amplitudes",
    "goa_cache_info",
    "goa_extinction_efficiency",
    "mie_amplitudes",
    "mueller_matrix",
    "phase_function",
    "resolve_method",
    "size_parameter",
]
from ._version import __version__  # noqa: E402

from .discrete import DEFAULT_CELLS_PER_PARTICLE, DEFAULT_CONTINUOUS_COUNT, DEFAULT_GRAIN_DEPTH, DEFAULT_TAU_MAX, DiscreteMedium  # noqa: E402
from .plugins import native_variants, register, set_evaluated_mode, set_variant  # noqa: E402

__all__ += ["MotesError", "DEFAULT_CELLS_PER_PARTICLE", "DEFAULT_CONTINUOUS_COUNT", "DEFAULT_GRAIN_DEPTH", "DEFAULT_TAU_MAX", "DEFAULT_TRUNCATE_RAD", "DiscreteMedium", "native_variants", "register", "set_evaluated_mode", "set_variant"]


def _register_if_mitsuba_is_ready() -> None:
    """``import motes`` after ``mi.set_variant(...)`` registers the plugins for that variant."""
    import sys

    mi = sys.modules.get("mitsuba")
    if mi is not None and getattr(mi, "variant", lambda: None)() is not None:
        register()


_register_if_mitsuba_is_ready()
