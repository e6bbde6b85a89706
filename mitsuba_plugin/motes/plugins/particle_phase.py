"""Mitsuba phase function ``particle``: the phase function of the particle(s) that scattered the path.

=============  ======  ==========================================================================
Parameter      Type    Meaning
=============  ======  ==========================================================================
(none)                 Use it as the ``<phase>`` child of a ``discrete`` medium, which supplies the
                       particles; used elsewhere it raises a one-sentence error at the first call.
=============  ======  ==========================================================================

Notes
-----
* At an interaction the ``discrete`` medium knows which site (normally one particle; particles that
  coincide along the ray form a mixture) scattered the path; this phase function evaluates and samples
  that site's mixture: per channel ``f_c = sum_j s_jc f_jc / sum_j s_jc`` with scattering weights
  ``s_jc = tau_j * albedo_jc`` — sigma_s f equals Q(theta) of the paper's Eq. 24 for those particles.
* ``sample`` picks a channel uniformly, a particle by its scattering weight, then draws from its
  tabulated phase function; the pdf it returns (and ``eval_pdf`` returns) is the mean over channels of
  ``f_c``, so sampling and evaluation agree exactly, and the weights ``f_c / pdf`` stay bounded across
  wavelengths (spectral variants interpolate between the tabulated wavelengths).
* Every call is one batch to Rust (numpy in, numpy out); in LLVM variants it needs the evaluated
  ("wavefront") mode that ``motes.set_variant`` switches on.
* Polarised variants: where the grains' phase function is their own, ``eval_pdf`` returns their Mueller matrix
  (Bohren & Huffman's F11, F12, F33, F34 of the site's mixture, rotated into Mitsuba's Stokes frames:
  ``_bridge.mueller_spectrum``) and ``sample`` that matrix over the pdf of the direction it drew from F11;
  elsewhere (a user's phase function, ``phase_model = "hg"``) a depolarizer, as Mitsuba's own phase functions.
* On the native render path (``motes/native/motes_native.cpp``, which this plugin hands its calls to in
  symbolic mode) the values and weights are ``albedo_c f_c`` and ``albedo_c f_c / pdf`` instead, and the
  medium's sigma_s equals sigma_t at every site: the path carries the same product (``discrete``'s notes,
  "Render paths").
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ._bridge import (bind_to_variant, channel_wavelengths, depolarized, floats, mueller_spectrum, spectrum, symbolic_mode,
                      vec3, vector3)


class ParticlePhase:
    """Methods of the plugin; ``plugin_class()`` binds them to the current variant's ``mi.PhaseFunction``."""

    def __init__(self, props: mi.Properties):
        mi.PhaseFunction.__init__(self, props)
        self.m_flags = mi.PhaseFunctionFlags.Anisotropic
        self._medium = None  # motes.discrete.DiscreteMedium, set by the discrete medium
        self._native = None  # its native phase function (motes.native), when that path is in use
        self._drjit = None  # kernel = "drjit": the medium's drjit_medium.DrJitKernel

    is_motes_particle_phase = True

    def attach(self, medium, native=None, drjit=None) -> None:
        """``medium``: the ``motes.DiscreteMedium``, or for a medium that fills its holders the
        ``_scene.PendingFill`` that makes it (its ``result()``, read at the first call); ``native``: the native
        phase function, or ``drjit``: the medium's ``drjit_medium.DrJitKernel`` (``kernel = "drjit"``)."""
        self._medium = medium
        self._native = native
        self._drjit = drjit

    def sample(self, ctx, mei, sample1, sample2, active=True):
        if self._drjit is not None:
            return self._drjit.sample(ctx, mei, sample1, sample2, active)
        if self._native is not None and symbolic_mode():
            return self._native.sample(ctx, mei, sample1, sample2, active)
        n = max(np.size(np.asarray(sample1)), np.size(np.asarray(sample2.x)), dr.width(mei.p), dr.width(mei.wi))
        p, wi = vec3(mei.p, n), vec3(mei.wi, n)
        self._medium = _require_medium(self._medium)
        lam, ch = self._channels(mei, n)
        u1 = np.ascontiguousarray(np.broadcast_to(np.asarray(sample1, dtype=np.float64).ravel(), (n,)))
        u2 = np.ascontiguousarray(np.stack([np.broadcast_to(np.asarray(sample2.x, dtype=np.float64).ravel(), (n,)),
                                            np.broadcast_to(np.asarray(sample2.y, dtype=np.float64).ravel(), (n,))], axis=1).ravel())
        wo, w, pdf = self._medium.core.phase_sample(p.ravel(), wi.ravel(), lam, ch, u1, u2)
        if self._polarizing():  # the weight is the matrix there over the pdf (the sampling is F11's)
            wo_v = vector3(wo.reshape(n, 3))
            m = self._mueller(ctx, mei, wo_v, p, wi, wo.reshape(n, 3).astype(np.float32), lam, ch, n)
            inv = np.where(pdf > 0, 1.0 / np.where(pdf > 0, pdf, 1.0), 0.0)
            return wo_v, m * floats(inv), floats(pdf)
        return vector3(wo.reshape(n, 3)), depolarized(spectrum(w.reshape(n, ch), n)), floats(pdf)

    def eval_pdf(self, ctx, mei, wo, active=True):
        if self._drjit is not None:
            return self._drjit.eval_pdf(ctx, mei, wo, active)
        if self._native is not None and symbolic_mode():
            return self._native.eval_pdf(ctx, mei, wo, active)
        n = max(dr.width(mei.p), dr.width(mei.wi), dr.width(wo))
        p, wi, w = vec3(mei.p, n), vec3(mei.wi, n), vec3(wo, n)
        self._medium = _require_medium(self._medium)
        lam, ch = self._channels(mei, n)
        if self._polarizing():
            elements, pdf = self._medium.core.phase_mueller(p.ravel(), wi.ravel(), w.ravel(), lam, ch)
            return mueller_spectrum(elements.reshape(n, ch, 4), n, ctx, mei, wo), floats(pdf)
        v, pdf = self._medium.core.phase_eval(p.ravel(), wi.ravel(), w.ravel(), lam, ch)
        return depolarized(spectrum(v.reshape(n, ch), n)), floats(pdf)

    def _polarizing(self) -> bool:
        """Polarised variants whose grains carry their Mueller matrices (``discrete``'s ``_polarizing``)."""
        return bool(mi.is_polarized) and self._medium.core.polarizes

    def _mueller(self, ctx, mei, wo_v, p, wi, wo, lam, ch, n):
        elements, _ = self._medium.core.phase_mueller(p.ravel(), wi.ravel(), wo.ravel(), lam, ch)
        return mueller_spectrum(elements.reshape(n, ch, 4), n, ctx, mei, wo_v)

    def _channels(self, mei, n):
        return channel_wavelengths(self._medium, mei, n)

    def to_string(self):
        return f"ParticlePhase[attached={self._medium is not None}]"


def _require_medium(medium):
    """The medium's data (a pending one's, made now: ``attach``), or the error of a phase function outside one."""
    if medium is None:
        raise RuntimeError('motes: <phase type="particle"/> works only inside a <medium type="discrete">, which '
                           "supplies its particles; use hg, tabphase or another phase function in other media")
    return medium.result() if hasattr(medium, "result") else medium


_classes: dict = {}


def plugin_class():
    """The plugin class for the current Mitsuba variant."""
    return bind_to_variant(ParticlePhase, "PhaseFunction", "ParticlePhase", _classes)
