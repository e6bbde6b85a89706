"""What the integrator may skip around each ``discrete`` medium (issue 25): the phase function's evaluation towards a
light whose shadow ray a site of the medium blocks for certain (the convex shapes that hold the medium,
``rust/motes-core/src/render/enclosure.rs``), and the part of a ray beyond its site (Mitsuba's ``is_homogeneous``).

Mitsuba's ``volpath`` and ``volpathmis`` trace a shadow ray from a scattering event towards a light, then evaluate
the phase function towards it and multiply the two: where the ray ends at a site of the medium the light is zero, and
so is the product, whatever the phase function says. The medium sees its own sites but not the scene's surfaces, and
Mitsuba keeps a site only where no surface comes first along the ray. A convex shape whose interior is the medium
holds the whole segment from an event inside it to a site inside it, so no boundary of the medium comes first; any
other surface inside it blocks a shadow ray by itself unless it lets rays through unchanged (a ``null`` or
thin-glass BSDF: Mitsuba's ``BSDFFlags.Null``, e.g. a nested medium's boundary).

Mitsuba's ``is_homogeneous`` flag, in ``volpath`` and ``volpathmis``, does one thing: a ray that has a medium
interaction is intersected with the scene only up to it (Embree stops there instead of at the far wall of the room).
That is exact for any medium without null collisions, and a ``discrete`` medium has none (every site it returns
scatters), so ``set_enclosures`` sets it for those two integrators and clears it for any other (``prbvolpath``
computes a homogeneous medium's transmittance in closed form instead, which this medium does not have).

``set_enclosures(scene, integrator)`` (None: neither skip) gives each ``discrete`` medium of the scene the shapes that hold it:
``cube`` shapes and any other closed convex triangle mesh of at most ``MAX_FACES`` triangles (their face planes;
the core rejects open or non-convex meshes), and ``sphere`` shapes (a ball, where its bounding box is a cube). It
gives none (every evaluation computed, the default) where

* the integrator is not ``volpath`` or ``volpathmis`` (another may evaluate the phase function for another use:
  ``prbvolpath``'s adjoint pass replays its evaluations);
* the scene holds instances (their shapes are not visible here);
* for one holder: another shape that lets shadow rays through (``BSDFFlags.Null``), the medium's other holders
  included, reaches into its bounding box (a ray that crosses it leaves the holder's medium or enters another).

The core answers one evaluation per blocked free flight (the light's), and a phase sample never returns pdf 0 at a
site (a site that scatters nothing gives a zero weight with pdf 1): volpath keeps a path whose sample has pdf 0 on
its old ray, which the flag has cut at the site.

The wrapped ``mi.render`` (``motes.plugins.cameras``) sets both for the integrator given to it, or the scene's, and
clears the flag when the call returns (its kernels are traced by then; the enclosure stays, for kernels that run
later, until the next ``mi.render`` sets it again). After a load both are off, so that ``Integrator.render`` called
directly, with any integrator, computes everything; ``motes.plugins.cameras.attach(scene, integrator=...)`` turns
them on for a direct call with ``volpath`` or ``volpathmis``.
"""

from __future__ import annotations

import numpy as np

from . import _scene

#: Integrators whose next-event estimation multiplies the phase value by the light the shadow ray sees.
SKIPPING_INTEGRATORS = ("VolumetricPathIntegrator", "VolpathMisIntegratorImpl")  # Mitsuba 3.9's class names

#: Largest mesh (in triangles) read as a region: every point is tested against every distinct face plane.
MAX_FACES = 128


def _lets_shadow_rays_through(shape) -> bool:
    import mitsuba as mi

    bsdf = shape.bsdf() if hasattr(shape, "bsdf") else None
    return bsdf is None or bool(int(bsdf.flags()) & int(mi.BSDFFlags.Null))


def _region_of(shape):
    """("mesh", vertices, faces), ("ball", centre, radius) or None for a shape the rule cannot use."""
    if shape.is_mesh():
        if shape.face_count() > MAX_FACES:
            return None
        vertices = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
        faces = np.array(shape.faces_buffer(), dtype=np.uint32).reshape(-1, 3)
        return ("mesh", vertices, faces)
    if shape.class_name() == "Sphere":
        box = shape.bbox()
        lo, hi = np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)
        half = 0.5 * (hi - lo)
        if not np.all(half > 0) or np.ptp(half) > 1e-6 * half.max():
            return None  # not a ball (a sphere scaled unevenly)
        return ("ball", tuple(0.5 * (lo + hi)), float(half.min()))
    return None


def _overlaps(a, b) -> bool:
    return all(a.min[k] <= b.max[k] and b.min[k] <= a.max[k] for k in range(3))


def integrator_skips(integrator) -> bool:
    """Does this integrator multiply the phase value of next-event estimation by the light its shadow ray sees?"""
    return integrator is not None and integrator.class_name() in SKIPPING_INTEGRATORS


def _set_clips_rays(medium, on: bool) -> None:
    """Set ``is_homogeneous`` on a ``discrete`` medium object: the native one (scalar variants) through the C++
    plugin, the Python one (LLVM variants) directly."""
    from .. import native

    if not native.set_clips_rays(medium, on):
        medium.m_is_homogeneous = bool(on)


def clear_clips(scene, objects=None) -> None:
    """Let no integrator clip rays at the sites of the scene's ``discrete`` media (the flag as built): what
    ``mi.render`` leaves behind, once the render it set the flag for has traced its kernels. ``objects``: those
    media's objects where the caller has them (``cameras.attach`` returns them)."""
    for m in _scene.discrete_medium_objects(scene) if objects is None else objects:
        _set_clips_rays(m, False)


def set_enclosures(scene, integrator=None, objects=None) -> None:
    """Set on each ``discrete`` medium of ``scene`` the shapes that hold it and whether integrators may clip its rays
    at their sites (module docs), for ``integrator``, the one about to render; None: neither (the default state).
    ``objects``: the scene's discrete medium objects where the caller has them."""
    shapes = list(scene.shapes())
    skips = integrator is not None and integrator_skips(integrator)
    for m in _scene.discrete_medium_objects(scene) if objects is None else objects:
        _set_clips_rays(m, skips)
    holders = {}  # id(data) -> (data, [shape])
    for s in shapes:
        data = _scene.data_of(s.interior_medium()) if s.is_medium_transition() else None
        if data is not None:
            holders.setdefault(id(data), (data, []))[1].append(s)
    usable = skips and not any(s.class_name() in ("Instance", "ShapeGroup") for s in shapes)
    passing = [s for s in shapes if _lets_shadow_rays_through(s)]
    for data, hs in holders.values():
        meshes, balls = [], []
        for h in hs if usable else ():
            # Any other surface that lets shadow rays through, the medium's other holders included (a ray
            # crossing one leaves this holder's medium or enters another's), rules the holder out.
            if any(p is not h and _overlaps(p.bbox(), h.bbox()) for p in passing):
                continue
            region = _region_of(h)
            if region is None:
                continue
            if region[0] == "mesh":
                meshes.append(region[1:])
            else:
                balls.append(region[1:])
        data.set_enclosure(meshes, balls)


__all__ = ["MAX_FACES", "SKIPPING_INTEGRATORS", "clear_clips", "integrator_skips", "set_enclosures"]
