"""Dr.Jit <-> numpy conversions shared by the plugins: one batch per call, scalar and JIT variants alike."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def is_jit() -> bool:
    """Whether the current variant is a JIT (LLVM/CUDA) one: batches of lanes rather than one."""
    return dr.is_jit_v(mi.Float)


def symbolic_mode() -> bool:
    """Whether Dr.Jit traces loops and calls symbolically on this thread (Mitsuba's default; scalar
    variants count as symbolic: a path runs on one thread there too). The native plugins keep per-thread
    state and need it (``rust/motes-core/src/render/discrete/packet.rs``, "One packet at a time")."""
    return not is_jit() or (dr.flag(dr.JitFlag.SymbolicLoops) and dr.flag(dr.JitFlag.SymbolicCalls))


def require_evaluated_mode() -> None:
    """One-sentence error instead of Dr.Jit's ``jit_var_schedule ... not permitted`` when a JIT render runs
    in symbolic mode (e.g. from a thread that never switched: Dr.Jit's flags are per thread)."""
    if is_jit() and (dr.flag(dr.JitFlag.SymbolicLoops) or dr.flag(dr.JitFlag.SymbolicCalls)):
        raise RuntimeError("motes: the discrete medium needs Dr.Jit's evaluated mode on the rendering thread; "
                           "call motes.set_evaluated_mode() (or motes.set_variant(...)) in that thread first")


def vec3(v, n: int = 0) -> np.ndarray:
    """(n, 3) float32 array of a Dr.Jit 3-vector (broadcast to at least n lanes; 1 in scalar variants)."""
    cols = [np.atleast_1d(np.asarray(c, dtype=np.float32)) for c in (v.x, v.y, v.z)]
    n = max([n] + [c.size for c in cols])
    return np.ascontiguousarray(np.stack([np.broadcast_to(c, (n,)) for c in cols], axis=1))


def mask(m, n: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(np.atleast_1d(np.asarray(m, dtype=bool)), (n,)))


def floats(a: np.ndarray):
    a = np.asarray(a, dtype=np.float32)
    return mi.Float(a) if is_jit() else float(a[0])


def vector3(a: np.ndarray):
    a = np.asarray(a, dtype=np.float32)
    if is_jit():
        return mi.Vector3f(mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2]))
    return mi.Vector3f(*(float(x) for x in a[0]))


def spectrum(a: np.ndarray, n: int):
    """An ``UnpolarizedSpectrum`` from (n, channels) values (a single column is broadcast)."""
    a = np.asarray(a, dtype=np.float32)
    size = dr.size_v(mi.UnpolarizedSpectrum)
    if a.shape[1] == 1 and size != 1:
        a = np.repeat(a, size, axis=1)
    if is_jit():
        return mi.UnpolarizedSpectrum(*(mi.Float(np.ascontiguousarray(a[:, c])) for c in range(size)))
    return mi.UnpolarizedSpectrum(*(float(a[0, c]) for c in range(size)))


def depolarized(value):
    """``value`` (an ``UnpolarizedSpectrum``) as the variant's ``Spectrum``: in polarised variants a depolarizer
    (only its (0, 0) element), as Mitsuba's own phase functions return."""
    if mi.is_polarized:
        return mi.mueller.depolarizer(value)
    return value


def mueller_spectrum(elements: np.ndarray, n: int, ctx, mei, wo):
    """The Mueller matrix (a polarised variant's ``Spectrum``) of grains whose Bohren & Huffman elements F11, F12,
    F33, F34 per channel are ``elements`` (n, channels, 4), in Mitsuba's Stokes frames: as the native plugin
    (``motes_native.cpp``, "Polarised variants") builds it — light arrives along -wo and leaves along wi (swapped
    in importance transport), the scattering plane's in-plane axes rotated into ``mueller.stokes_basis``."""
    return mueller_of([spectrum(elements[:, :, k], n) for k in range(4)], n, ctx, mei, wo)


def mueller_of(f: list, n: int, ctx, mei, wo):
    """``mueller_spectrum`` from the elements F11, F12, F33, F34 as the variant's ``UnpolarizedSpectrum`` each
    (``f``; Dr.Jit values, so that a kernel traced in symbolic mode builds it too)."""
    m = dr.zeros(mi.Spectrum, n) if is_jit() else dr.zeros(mi.Spectrum)
    m[0, 0], m[0, 1], m[1, 0], m[1, 1] = f[0], f[1], f[1], f[0]
    m[2, 2], m[2, 3], m[3, 2], m[3, 3] = f[2], f[3], -f[3], f[2]
    wi = mei.wi
    radiance = ctx.mode == mi.TransportMode.Radiance
    wo_hat, wi_hat = (wo, wi) if radiance else (wi, wo)
    d_in, d_out = -wo_hat, mi.Vector3f(wi_hat)
    normal = dr.cross(d_in, d_out)
    n2 = dr.squared_norm(normal)
    normal = dr.select(n2 > 1e-12, normal * dr.rsqrt(dr.maximum(n2, 1e-30)), mi.coordinate_system(d_in)[0])
    x_in, x_out = dr.normalize(dr.cross(normal, d_in)), dr.normalize(dr.cross(normal, d_out))
    return mi.mueller.rotate_mueller_basis(m, d_in, x_in, mi.mueller.stokes_basis(d_in), d_out, x_out,
                                           mi.mueller.stokes_basis(d_out))


def channel_wavelengths(medium, mei, n: int):
    """(flat wavelengths in nm, channels): per lane in spectral variants, shared in RGB ones."""
    if mi.is_spectral:
        w = mei.wavelengths
        cols = [np.atleast_1d(np.asarray(w[c], dtype=np.float64)) for c in range(dr.size_v(mi.UnpolarizedSpectrum))]
        cols = [np.broadcast_to(c, (n,)) for c in cols]
        return np.ascontiguousarray(np.stack(cols, axis=1).ravel()), len(cols)
    if mi.is_rgb:
        return medium.channel_wavelength_nm, medium.channel_wavelength_nm.size
    # monochrome: the middle tabulated wavelength
    lam = medium.channel_wavelength_nm
    return np.ascontiguousarray(lam[[lam.size // 2]]), 1


def bind_to_variant(methods_class, base_name: str, name: str, cache: dict):
    """A subclass of the current variant's ``mi.<base_name>`` carrying ``methods_class``'s methods, made once
    per variant (Mitsuba's base classes are per variant; nanobind allows a single base, so the methods are
    copied rather than mixed in)."""
    variant = mi.variant()
    if variant not in cache:
        methods = {k: v for k, v in vars(methods_class).items() if k not in ("__dict__", "__weakref__")}
        cache[variant] = type(name, (getattr(mi, base_name),), methods)
    return cache[variant]
