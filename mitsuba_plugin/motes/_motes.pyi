"""Type stub of the compiled extension ``motes._motes`` (Rust, pyo3).

Every function takes flat float64 arrays of one common length (the Python layer broadcasts), releases
the GIL and runs in parallel. Invalid values raise ``MotesError`` (a ``ValueError``) naming the argument.
"""

from typing import Any, Sequence

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
#: Ray segments of a query: (origins (3n,), directions (3n,), t0 (n,), t1 (n,)).
Segments = tuple[F64, F64, F64, F64]
C128 = npt.NDArray[np.complex128]

def mie_amplitudes(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   theta: F64) -> tuple[C128, C128]: ...
def goa_amplitudes(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   theta: F64, p_max: int, diffraction: bool, regularise: bool,
                   edge_correction: bool) -> tuple[C128, C128]: ...
def cross_sections(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   method: str, hybrid_radius_um: float, p_max: int, regularise: bool,
                   edge_correction: bool, with_g: bool) -> tuple[F64, F64, F64, F64]: ...
def phase_function(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   theta: F64, method: str, hybrid_radius_um: float, p_max: int, regularise: bool,
                   edge_correction: bool) -> F64: ...
def mueller_matrix(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   theta: F64, method: str, hybrid_radius_um: float, p_max: int, regularise: bool,
                   edge_correction: bool, normalize: bool) -> npt.NDArray[np.float64]:
    """(n, 4): F11, F12, F33, F34 (Bohren & Huffman), F11 = phase_function when normalize."""
def clear_goa_cache() -> None: ...
def goa_cache_info() -> tuple[int, int]: ...
def goa_extinction_efficiency(alpha: F64, eta_re: F64, eta_im: F64, p_max: int, regularise: bool,
                              edge_correction: bool) -> F64: ...
def policy_constants() -> tuple[float, float, float]: ...
def resolve_method(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   method: str, hybrid_radius_um: float, p_max: int) -> list[str]: ...
class Psd:
    """A PSD parsed and validated once from its JSON spec (rust/motes-py/src/psd.rs); picklable."""
    def __init__(self, spec: str) -> None: ...
    def spec(self) -> str: ...
    def eval(self, what: str, x: F64) -> F64: ...
    def sample(self, n: int, seed: int) -> F64: ...
    def quadrature(self, max_log_step: float) -> tuple[F64, F64]: ...
    def support(self) -> tuple[tuple[float, float], list[tuple[float, float]]]: ...

def bulk_properties(psd_specs: list[str], shares: list[float], eta_re: F64, eta_im: F64, wavelength_um: F64,
                    number_density_m3: float, eta_medium: float, method: str, hybrid_radius_um: float,
                    p_max: int, max_log_step: float, mie_dx: float | None, theta: F64, with_phase: bool,
                    truncate_below_rad: float, refine_tol: float, refine_max_nodes: int,
                    goa_cache: GoaCache | None, mueller: bool
                    ) -> tuple[F64, F64, F64, F64, npt.NDArray[np.float64], F64, F64, F64, npt.NDArray[np.float64] | None]:
    """The last element: with ``mueller``, (n_wavelengths, 3, n_theta) ratios F12/F11, F33/F11, F34/F11."""
class GoaCache:
    """GOA ray geometry shared by several bulk_properties calls (a medium's size bins)."""
    def __init__(self) -> None: ...
    def __len__(self) -> int: ...
class PhaseTable:
    """A tabulated phase function validated and prepared once (rust/motes-py/src/ensemble.rs); picklable."""
    def __init__(self, theta: F64, f: F64) -> None: ...
    def eval(self, query: F64) -> F64: ...
    def sample(self, u: F64) -> F64: ...
    def regular_mu(self, n: int) -> F64: ...
    def mean_cosine(self) -> float:
        """g = integral of f cos(theta) over the sphere (exact for the table's interpolant)."""
def henyey_greenstein(g: float, theta: F64) -> F64:
    """Henyey-Greenstein phase function (1/sr) with asymmetry g in (-1, 1) at angles theta (radians)."""
def material_index(name: str, wavelength_um: F64) -> C128: ...
def core_hash() -> str: ...
def density_at(kind: str, params: Sequence[float], noise_seed: int, points: F64, lo: Sequence[float],
               hi: Sequence[float]) -> F64:
    """The density ``kind`` (params as ``generate_cloud``; "grid" with [nx, ny, nz, values x fastest]) at the flat
    ``points`` (n*3, the cloud's coordinates) over the box [lo, hi]: a grid interpolates trilinearly between
    cell centres, clamped at the faces, as Mitsuba's gridvolume."""
def generate_cloud(count: int, lo: Sequence[float], hi: Sequence[float], kind: str, params: Sequence[float],
                   noise_seed: int, psds: Sequence[Psd], shares: Sequence[float], seed: int,
                   transform: Sequence[Sequence[float]]) -> tuple[F64, F64, npt.NDArray[np.uint32]]:
    """Exactly ``count`` particles in [lo, hi] after a density (``kind`` "uniform"; "gradient" with params
    [axis, start, end]; "noise" with params [scale, octaves, contrast] and ``noise_seed``), species by
    ``shares`` with radii from ``psds``, centres through ``transform`` (3x4): flat centres (count*3), radii
    (um), species indices (rust/motes-core/src/space/cloud.rs)."""
def value_noise(points: F64, scale: float, octaves: int, seed: int, contrast: float) -> F64:
    """fBm value noise v(x) in [0, 1] at points (n*3) (rust/motes-core/src/space/cloud.rs)."""
def move_grains(centres: F64, velocity: Sequence[float], turbulence: float, turbulence_scale: float, seed: int,
                time: float, wrap_to_world: Sequence[Sequence[float]] | None = None) -> F64:
    """Rest positions (n*3) moved to ``time`` by a velocity and a divergence-free turbulent drift, wrapped
    around the box [-1, 1]^3 that ``wrap_to_world`` (3x4) maps into the scene when given
    (rust/motes-core/src/space/motion.rs); a new array."""
def default_wavelengths() -> tuple[list[float], list[float]]: ...
def simd_walk() -> str: ...

class ParticleGrid:
    def __init__(self, positions: F64, radius: F64, c_ext: F64, channels: int, query_radius: float,
                 cells_per_particle: float) -> None: ...
    def optical_depth(self, segments: Segments, brute: bool) -> F64: ...
    def free_flight(self, segments: Segments, u: F64,
                    channel: int) -> tuple[F64, npt.NDArray[np.int64], F64]: ...
    def occupied_interval(self, segments: Segments, brute: bool) -> tuple[F64, F64]: ...
    def flat_arrays(self, channel: int) -> dict[str, npt.NDArray[np.generic]]:
        """The grains as flat arrays in the centre-cell layout (rust/motes-core/src/space/grid/flat.rs), for a
        walk written outside the core (``motes.drjit_walk``): "spheres" (n, 4) float32 centre and inclusion
        radius R_i = r_c + r_i, "tau" (n,) float32 the disk's optical depth in ``channel``, "index" (n,) uint32
        the particle's index, "start" uint32 each cell's first grain (per class, cells + 1 entries, x fastest);
        per size class: "class_lo" (C, 3), "class_cell" (C,), "class_dims" (C, 3) int64, "class_reach" (C,)
        (its largest R with the grid's margin), "class_start" (C,) int64 its first entry of "start",
        "class_grains" (C + 1,) int64 its first grain. 24 bytes a grain (16 read per grain a walk tests)."""
    @property
    def bytes(self) -> int: ...
    @property
    def dims(self) -> tuple[int, int, int]: ...
    @property
    def channels(self) -> int: ...
    def __len__(self) -> int: ...


F32 = npt.NDArray[np.float32]


class MediumSettings:
    """A discrete medium's settings (rust/motes-core/src/render/discrete/settings.rs); every keyword defaults to
    the core's own default. storage is "compact" or "full" (checked here: MotesError naming it)."""

    def __init__(self, *, query_radius: float | None = None, tau_max: float | None = None,
                 cells_per_particle: float | None = None, continuous_count: float | None = None,
                 seed: int | None = None, storage: str | None = None, cache_bytes: int | None = None) -> None: ...
    query_radius: float
    tau_max: float
    cells_per_particle: float
    continuous_count: float
    seed: int
    storage: str
    cache_bytes: int


class BinTables:
    """Each optics bin's albedo (bins*K) and phase tables (flat theta/f, offsets bins*K + 1 ending at len(theta))
    at K wavelengths lambda_ (nm, increasing); optionally ``mueller``, per table (as ``offsets`` cut ``theta``)
    three rows F12/F11, F33/F11, F34/F11 of its length (polarised variants)."""

    def __init__(self, albedo: F64, theta: F64, f: F64, offsets: npt.NDArray[np.uint64], lambda_: F64,
                 mueller: F64 | None = None) -> None: ...
    def __len__(self) -> int: ...


def check_discrete_inputs(positions: F64, radius: F64, settings: MediumSettings) -> None:
    """The core's checks of a particle set and the medium's settings (raises MotesError)."""

class DiscreteMedium:
    """The discrete medium as the renderer queries it (rust/motes-core/src/render/discrete/)."""

    def __init__(self, positions: F64, radius: F64, q_ext: F64, bin: npt.NDArray[np.uint32], tables: BinTables,
                 settings: MediumSettings, radius_scale: float = 1.0, holders: Holders | None = None,
                 density: tuple[str, list[float], int, list[float], list[float], list[list[float]]] | None = None
                 ) -> None:
        """radius x radius_scale in scene units (radii in um pass their scale, not a scaled copy); q_ext: each
        bin's grey extinction efficiency (C_ext = pi r^2 q_ext); holders: the shapes the particles fill, to whose
        inside the continuous fields are confined; density: (kind, params, noise seed, box lo, box hi, transform
        3x4), the density the particles were drawn from, which then spreads the grains' continuous equivalent."""
    @staticmethod
    def procedural(count: float, box_: tuple[list[float], list[float]], density: tuple[str, list[float], int],
                   species: tuple[list[Psd], list[float]], cloud_seed: int, transform: list[list[float]],
                   scene_per_um: float, bins: tuple[list[list[float]], list[int], list[float]], tables: BinTables,
                   settings: MediumSettings, *, turbulence: float = 0.0, turbulence_scale: float = 1.0,
                   time: float = 0.0) -> DiscreteMedium:
        """A procedural cloud: no particle stored, bricks generated on demand
        (rust/motes-core/src/render/procedural.rs); bins: per species its bins' edges (um) and first global bin,
        and q_ext per global bin."""
    @property
    def bricks_built(self) -> int: ...
    @property
    def procedural_cloud(self) -> bool: ...
    def sample_sites(self, origins: F32, directions: F32, t_max: F64,
                     remember: npt.NDArray[np.bool_]) -> tuple[F64, F64]: ...
    def commit_events(self, p: F32, active: npt.NDArray[np.bool_], lambda_: F64, channels: int) -> F64: ...
    def phase_eval(self, p: F32, wi: F32, wo: F32, lambda_: F64, channels: int) -> tuple[F64, F64]: ...
    def phase_mueller(self, p: F32, wi: F32, wo: F32, lambda_: F64, channels: int) -> tuple[F64, F64]:
        """Polarised variants: (n*channels*4 Bohren & Huffman elements F11, F12, F33, F34 per channel, pdf n)."""
    @property
    def polarizes(self) -> bool:
        """Whether the medium's bins carry Mueller ratios (its grains polarise)."""
    def phase_sample(self, p: F32, wi: F32, lambda_: F64, channels: int, u1: F64, u2: F64) -> tuple[F64, F64, F64]: ...
    def local_scattering(self, points: F64, mu: F64, lambda_: F64, channels: int) -> tuple[F64, F64]: ...
    def sample_local(self, points: F64, w_in: F64, lambda_: F64, channels: int, u1: F64,
                     u2: F64) -> tuple[F64, F64, F64]: ...
    def insert_event(self, p: tuple[float, float, float], particles: list[int]) -> None:
        """Remember an event of ``particles`` at ``p`` (tests and tools): indices with full storage, positions in
        the grid with compact storage."""
    def optical_depth(self, segments: Segments) -> F64: ...
    def flat_tables(self) -> dict[str, npt.NDArray[np.generic]]:
        """The bins' optics tables as flat arrays: "mu", "f", "cdf" (table i's nodes at offset[i]..offset[i + 1]:
        increasing mu, f normalised, P(mu' <= mu)), "mueller" (F12/F11, F33/F11, F34/F11 per node, float32, 0 where
        a bin depolarises), "offset", and "albedo" per table; table ``bin * n_lambda + k`` at tabulated wavelength
        k."""
        ...
    def flat_arrays(self) -> dict[str, npt.NDArray[np.generic]] | None:
        """The grains walked one by one as ``ParticleGrid.flat_arrays`` gives them (grey tau; "index": what the
        medium names a grain by) and "bin" (n,) uint32 each grain's optics bin; None where no grain is stored
        (a procedural cloud, every size class continuous). Continuous size classes are not in it."""
    def flat_field(self) -> dict[str, npt.NDArray[np.generic]] | None:
        """The continuous field of the size classes no pixel resolves (not the grains' equivalent of
        ``grain_depth``): "lo", "cell" (3 each, float64), "dims" (3, uint32), "sigma" (per cell, float32, per scene
        unit, x fastest), "start" (cells + 1, uint32: cell c's entries start[c]..start[c + 1]) and per entry "bin"
        (uint32, the bins of ``flat_tables``) and "share" (float32, of its cell's extinction; one entry per bin);
        None without such a field (``motes.drjit_field``)."""
    def procedural_export(self) -> dict[str, Any] | None:
        """A procedural cloud's discrete process as numbers (``motes.drjit_procedural`` regenerates it): seed, tiling,
        Poisson constants, density terms, classes' codes and CDF, per class code "reach", "tau" (float32, as the
        bricks' grids store them) and "bin", transform and drift; None without procedural grains."""
    def procedural_tile_grains(self, tiles: list[int]) -> dict[str, npt.NDArray[np.generic]]:
        """The core's grains of ``tiles``: "candidates" per tile, and per grain "tile", "key", "code", "centre"
        (n*3, the cloud's coordinates) and "position" (n*3, scene units, after the drift)."""
    @property
    def widened(self) -> int: ...
    @property
    def albedo_scale(self) -> float: ...
    def set_albedo_scale(self, scale: float) -> None: ...
    @property
    def grain_depth(self) -> int: ...
    def set_grain_depth(self, depth: int) -> None: ...
    @property
    def cameras(self) -> list[tuple[tuple[float, float, float], float, float, tuple[float, float, float], float]]: ...
    @property
    def lights(self) -> list[tuple[tuple[float, float, float], float, float, tuple[float, float, float],
                                   tuple[float, float, float], float]] | None: ...
    def set_cameras(self, cameras: list[tuple[tuple[float, float, float], float, float, tuple[float, float, float],
                                              float]],
                    lights: list[tuple[tuple[float, float, float], float, float, tuple[float, float, float],
                                       tuple[float, float, float], float]] | None = None,
                    diffuse_surfaces: bool = False, samples_per_pixel: float = 0.0) -> None: ...
    def set_enclosure(self, meshes: list[tuple[npt.NDArray[np.float64], npt.NDArray[np.uint32]]] = ...,
                      balls: list[tuple[tuple[float, float, float], float]] = ...) -> int: ...
    @property
    def enclosure_regions(self) -> int: ...
    @property
    def diffuse_surfaces(self) -> bool: ...
    @property
    def samples_per_pixel(self) -> float: ...
    @property
    def surface_footprint(self) -> bool: ...
    def set_surface_footprint(self, on: bool) -> None: ...
    @property
    def surface_counts(self) -> tuple[int, int]: ...
    @property
    def tau_max(self) -> float: ...
    @property
    def reach_max(self) -> float: ...
    @property
    def continuous_particles(self) -> int: ...
    @property
    def bytes(self) -> int: ...
    @property
    def table_bytes(self) -> int: ...
    def __len__(self) -> int: ...
    # The native render path (rust/motes-py/src/native/): a handle for a C++ plugin, which keeps
    # ``owner`` alive until it releases the handle; (rays, events) it has rendered; references it holds.
    def native_handle(self, owner: object | None = None) -> int: ...
    def native_fill(self, handle: int, owner: object | None = None) -> None: ...
    @property
    def native_counts(self) -> tuple[int, int]: ...
    @property
    def native_references(self) -> int: ...

#: The box of points (n*3, float64): ((lo x, y, z), (hi x, y, z)), in parallel.
def bounding_box(points: F64) -> tuple[tuple[float, float, float], tuple[float, float, float]]: ...
#: Each radius's optics bin among increasing ``edges`` (``searchsorted(edges, radius, "right") - 1``, clipped to the
#: bins), as ``lookup[bin]`` where given; in parallel.
def size_bins(radius: F64, edges: F64, lookup: npt.NDArray[np.uint32] | None = None) -> npt.NDArray[np.uint32]: ...
#: The owner given with a handle a native plugin still holds, or None (unknown or released handles).
def native_owner(handle: int) -> object | None: ...
def native_pending_handle(owner: object | None = None) -> int:
    """A native handle without a core medium yet (every ray passes it) until DiscreteMedium.native_fill."""
def mesh_open_edges(vertices: F64, faces: npt.NDArray[np.uint32]) -> int:
    """Edges of a mesh (vertices welded by position) shared by an odd number of its faces (0: closed)."""

class Holders:
    """The closed shapes that hold a medium, in world space (rust/motes-core/src/space/inside.rs): meshes as
    (vertices n*3, faces m*3), Mitsuba's unit sphere and unit cylinder (solid) by their 3x4 to_world."""

    def __init__(self, meshes: Sequence[tuple[F64, npt.NDArray[np.uint32]]] = ...,
                 ellipsoids: Sequence[Sequence[Sequence[float]]] = ...,
                 cylinders: Sequence[Sequence[Sequence[float]]] = ...) -> None: ...
    def contains(self, points: F64) -> npt.NDArray[np.bool_]: ...
    def contains_brute(self, points: F64) -> npt.NDArray[np.bool_]: ...
    def volume(self, seed: int = 0) -> tuple[float, bool]: ...
    def fill(self, count: int, seed: int) -> F64: ...
    @property
    def bounds(self) -> tuple[list[float], list[float]]: ...
    def __len__(self) -> int: ...
#: Address and version of the native render path's C interface.
NATIVE_API: int
NATIVE_ABI: int

#: Default cap on a particle's optical depth (rust/motes-core/src/render/discrete/).
DEFAULT_TAU_MAX: float
#: Default bytes of a procedural cloud's bricks kept (rust/motes-core/src/render/procedural.rs).
DEFAULT_CACHE_BYTES: int
#: Default particles per query cylinder from which a size class is sampled as a continuous medium
#: (rust/motes-core/src/render/continuous/).
DEFAULT_CELLS_PER_PARTICLE: float
DEFAULT_CONTINUOUS_COUNT: float

# Ctrl-C of the `motes` command (rust/motes-py/src/interrupt.rs): a native thread reads the wakeup socket
# of signal.set_wakeup_fd and, on byte `signum`, prints the exit message and _exit()s with `status`.
def exit_on_wakeup(fd: int, signum: int, status: int) -> None: ...
def set_exit_message(message: str) -> None: ...

class MotesError(ValueError):
    """An invalid argument: `argument` names the parameter, `value` is what was given (None where the
    check concerns a whole array). Raised by every function of the core (rust/motes-py/src/convert.rs)."""

    argument: str
    value: float | int | str | None
