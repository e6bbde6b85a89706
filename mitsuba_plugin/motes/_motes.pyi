"""Type stub of the compiled extension ``motes._motes`` (Rust, pyo3).

Every function takes flat float64 arrays of one common length (the Python layer broadcasts), releases
the GIL and runs in parallel. Invalid values raise ``ValueError`` naming the argument.
"""

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
C128 = npt.NDArray[np.complex128]

def mie_amplitudes(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   theta: F64) -> tuple[C128, C128]: ...
def goa_amplitudes(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   theta: F64, p_max: int, diffraction: bool, regularise: bool,
                   edge_correction: bool) -> tuple[C128, C128]: ...
def cross_sections(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   method: str, hybrid_radius_um: float, p_max: int, regularise: bool,
                   edge_correction: bool) -> tuple[F64, F64, F64, F64]: ...
def phase_function(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   theta: F64, method: str, hybrid_radius_um: float, p_max: int, regularise: bool,
                   edge_correction: bool) -> F64: ...
def goa_extinction_efficiency(alpha: F64, eta_re: F64, eta_im: F64, p_max: int, regularise: bool,
                              edge_correction: bool) -> F64: ...
def policy_constants() -> tuple[float, float, float]: ...
def resolve_method(radius_um: F64, wavelength_um: F64, eta_re: F64, eta_im: F64, eta_medium: F64,
                   method: str, hybrid_radius_um: float, p_max: int) -> list[str]: ...
