"""The scene's cameras and lights, handed to its ``discrete`` media for the surface-ray rule
(``surface_footprint``).

A ray that starts on a surface may see the grains' continuous equivalent when the narrowest pixel footprint
it can carry holds many grains (``rust/motes-core/src/render/footprint.rs``); the medium needs each camera's
position, its narrowest angular pixel width and its lens aperture for that, and where the lights are that
shadow rays converge to (a grain near a lamp casts a large shadow). Mitsuba gives a medium no access to the
sensors or emitters, so ``attach(scene)`` reads them from the scene and sets them on every ``discrete``
medium in it: after every ``mi.load_file`` / ``mi.load_dict`` / ``mi.load_string`` and before every
``mi.render`` (both wrapped once per process by ``wrap_render`` and ``scene_checks.wrap_loaders``), so that
a camera moved through ``mi.traverse`` is seen at the next render. A caller that renders through
``Integrator.render`` directly after moving a camera calls ``attach(scene)`` itself.

Cameras: ``perspective`` and ``thinlens`` (anything with an ``x_fov``) and ``orthographic``. A scene with any
other sensor (radiance meters, batches) gets no cameras, and its rays from surfaces and cameras walk the grains.
Camera rays see the grains' continuous equivalent where their pixel holds enough grains for the render's samples
per pixel (``samples_per_pixel``: the ``spp`` given to ``mi.render``, else the sensor's sampler's).
Lights: point and spot lights (and any other light at a point) by position, a spot also by its cone (a shadow ray
from outside it carries nothing), area lights by a sphere around their shape's bounding box and a disc that lies on
them (rectangles, disks and spheres; its penumbra blurs the grains' shadows, counted only in scenes whose every
surface is diffuse); the sky and distant lights need none. An emitter of any other kind leaves the lights unknown
(every ray's end is then taken for a light).
Surfaces: whether every shape's BSDF is diffuse (``diffuse_only``) and every light at infinity a uniform sky
(``uniform_distant_light``); then rays bounced off a surface carry the grains blurred by the lobe, and may see their
continuous equivalent sooner.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np

from . import _scene, enclosure
# Re-exported: the scene's discrete media are looked up in ``_scene`` (below this module and ``enclosure``).
from ._scene import data_of, discrete_media, discrete_medium_objects  # noqa: F401

#: Discrete media constructed in this process (``attach`` does nothing before the first).
_made = [0]


def note_medium() -> None:
    _made[0] += 1


def _scalar(x) -> float:
    a = np.asarray(x, dtype=np.float64).ravel()
    return float(a[0])


def camera_of(sensor):
    """(position, narrowest angular pixel width in radians, aperture radius) of a pinhole or thin-lens
    camera, (position, 0, 0, viewing axis, pixel width in scene units) of an orthographic one, or None for
    any other sensor. A crop window changes neither: its pixels are the full film's."""
    import mitsuba as mi

    params = mi.traverse(sensor)
    width, height = (int(v) for v in sensor.film().size())
    m = np.asarray(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4, -1)[..., 0]
    position = tuple(float(v) for v in m[:3, 3] / m[3, 3])
    if not all(math.isfinite(v) for v in position):
        return None
    if "x_fov" not in params:
        if sensor.class_name() != "OrthographicCamera":
            return None
        # The local image plane spans 2 units across the width (2 / aspect across the height: square
        # pixels), scaled by to_world.
        scale = min(float(np.linalg.norm(m[:3, 0])), float(np.linalg.norm(m[:3, 1])))
        pixel_width = 2.0 * scale / max(width, 1)
        axis = m[:3, 2] / max(float(np.linalg.norm(m[:3, 2])), 1e-300)
        if not (pixel_width > 0 and math.isfinite(pixel_width) and np.all(np.isfinite(axis))):
            return None
        return position, 0.0, 0.0, tuple(float(v) for v in axis), pixel_width
    tan_half = math.tan(math.radians(_scalar(params["x_fov"])) / 2.0)
    # A pixel spans 2 tan(fov/2) / width of the image plane at unit distance: that angle at the centre,
    # cos²θ of it radially at field angle θ; the image's corners have the largest θ.
    tan_corner2 = tan_half**2 * (1.0 + (height / max(width, 1)) ** 2)
    pixel_angle = 2.0 * tan_half / max(width, 1) / (1.0 + tan_corner2)
    aperture = _scalar(params["aperture_radius"]) if "aperture_radius" in params else 0.0
    if not pixel_angle > 0:
        return None
    return position, pixel_angle, aperture


def cameras_of(scene, extra=None) -> list:
    """Every camera of the scene (and ``extra``, a sensor rendered that the scene does not hold); empty when
    any of them is not a pinhole, thin-lens or orthographic camera (the medium could not tell its rays)."""
    sensors = list(scene.sensors())
    if extra is not None and not any(extra == s for s in sensors):
        sensors.append(extra)
    cams = [camera_of(s) for s in sensors]
    return [] if any(c is None for c in cams) else cams


def samples_per_pixel(scene, sensor=None, spp: int = 0) -> int:
    """The spp a render will take: ``spp`` where given (> 0), else ``sensor``'s sampler's, else the most of any
    of the scene's sensors (at load, before the sensor to render is known: the strictest for camera rays)."""
    if spp and spp > 0:
        return int(spp)
    sensors = [sensor] if sensor is not None else list(scene.sensors())
    counts = [int(s.sampler().sample_count()) for s in sensors if s.sampler() is not None]
    return max(counts, default=0)


def light_of(emitter):
    """(centre, radius, disc, normal, spot axis, spot cos_cutoff) of a light at finite distance; () for one at
    infinity; None for one it cannot place. Point and spot lights: radius 0, no disc; a spot its cone (outside
    it, a shadow ray carries nothing). Area lights: the sphere around their shape's
    bounding box, and a disc that lies on the light (its penumbra blurs the grains' shadows:
    ``rust/motes-core/src/render/footprint.rs``): a rectangle's or disk's inscribed disc and normal, a
    sphere's outline (normal (0, 0, 0): seen whole from every side); none known (0) for any other shape."""
    import mitsuba as mi

    flags = int(emitter.flags())
    if flags & int(mi.EmitterFlags.Infinite):
        return ()
    shape = emitter.get_shape()
    if shape is not None:
        box = shape.bbox()
        lo, hi = (np.asarray(v, dtype=np.float64).ravel()[:3] for v in (box.min, box.max))
        centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
        disc, normal = _disc_of(shape, centre, lo, hi) if _spreads_its_light(emitter) else (0.0, (0.0, 0.0, 0.0))
        return tuple(float(v) for v in centre), radius, min(disc, radius), normal, _NO_SPOT[0], _NO_SPOT[1]
    if flags & int(mi.EmitterFlags.DeltaPosition):
        params = mi.traverse(emitter)
        if "position" in params:
            centre = np.asarray(params["position"], dtype=np.float64).ravel()[:3]
        else:
            m = np.asarray(emitter.world_transform().matrix, dtype=np.float64).reshape(4, 4, -1)[..., 0]
            centre = m[:3, 3] / m[3, 3]
        axis, cos_cutoff = _spot_cone(emitter)
        return tuple(float(v) for v in centre), 0.0, 0.0, (0.0, 0.0, 0.0), axis, cos_cutoff
    return None


#: (axis, cos_cutoff) of a light that shines every way.
_NO_SPOT = ((0.0, 0.0, 0.0), -1.0)


def _spot_cone(emitter) -> tuple:
    """(axis, cosine of the cutoff angle) of a ``spot`` light: outside that cone it lights nothing, and a shadow
    ray from there carries nothing; every way for any other light."""
    import mitsuba as mi

    if emitter.class_name() != "SpotLight":
        return _NO_SPOT
    params = mi.traverse(emitter)
    if "cutoff_angle" not in params:
        return _NO_SPOT
    cutoff = math.radians(_scalar(params["cutoff_angle"]))
    m = np.asarray(emitter.world_transform().matrix, dtype=np.float64).reshape(4, 4, -1)[..., 0]
    axis = m[:3, 2]
    norm = float(np.linalg.norm(axis))
    if not (norm > 0 and math.isfinite(norm) and 0 <= cutoff <= math.pi):
        return _NO_SPOT
    return tuple(float(v) for v in axis / norm), math.cos(cutoff)


def _spreads_its_light(emitter) -> bool:
    """Does an area light shine alike from all of its surface in all directions, so that its whole outline
    blurs the grains' shadows? Not a collimated one (``directionalarea``: shadows as sharp as the grains) nor one
    whose radiance is a texture (a hot spot casts narrow shadows)."""
    import mitsuba as mi

    if int(emitter.flags()) & int(mi.EmitterFlags.DeltaDirection):
        return False
    keys = [k for k in mi.traverse(emitter).keys() if k.startswith("radiance.")]
    return keys == ["radiance.value"]


def _disc_of(shape, centre, lo, hi) -> tuple:
    """(radius, normal) of a disc centred on ``centre`` that lies on an emitting shape (module docs)."""
    import mitsuba as mi

    kind = shape.class_name() if hasattr(shape, "class_name") else type(shape).__name__
    none = (0.0, (0.0, 0.0, 0.0))
    if kind == "Sphere":
        return float(np.min(hi - lo) / 2), (0.0, 0.0, 0.0)
    if kind not in ("Rectangle", "Disk"):
        return none
    params = mi.traverse(shape)
    if "to_world" not in params:
        return none
    m = np.asarray(params["to_world"].matrix, dtype=np.float64).reshape(4, 4, -1)[..., 0]
    u, v, o = m[:3, 0], m[:3, 1], m[:3, 3] / m[3, 3]
    n = np.cross(u, v)
    area = float(np.linalg.norm(n))
    if not (area > 0 and np.allclose(o, centre, atol=1e-6 * (1 + float(np.abs(centre).max())))):
        return none
    if kind == "Rectangle":  # [-1, 1]² by (u, v): its inscribed disc touches the nearer pair of sides
        radius = min(area / float(np.linalg.norm(u)), area / float(np.linalg.norm(v)))
    else:  # the unit disk by (u, v): an ellipse, whose inscribed disc is its least semi-axis
        radius = float(np.linalg.svd(np.stack([u, v], axis=1), compute_uv=False).min())
    return radius, tuple(float(x) for x in n / area)


def lights_of(scene):
    """The scene's lights at finite distance as (centre, radius, disc, normal) tuples, or None if any cannot be
    placed. The discs count only where every surface of the scene is diffuse (``diffuse_only``); elsewhere they
    are 0."""
    lights = [light_of(e) for e in scene.emitters()]
    if any(light is None for light in lights):
        return None
    lights = [light for light in lights if light]
    if not diffuse_only(scene):
        lights = [(c, r, 0.0, (0.0, 0.0, 0.0), axis, cos) for c, r, _, _, axis, cos in lights]
    return lights


def uniform_distant_light(scene) -> bool:
    """Is every light at infinity a uniform sky (``constant``)? A sun (``directional``) or an environment map (which
    may hold one) casts shadows of the grains as sharp as the grains, which a diffuse surface's lobe does not blur:
    its rays are its own, not the lobe's."""
    import mitsuba as mi

    infinite = int(mi.EmitterFlags.Infinite)
    return all(not int(e.flags()) & infinite or e.class_name() == "ConstantBackgroundEmitter" for e in scene.emitters())


def diffuse_only(scene) -> bool:
    """Does every shape of the scene reflect and transmit only diffusely (or let rays through unchanged, a null
    boundary), with no instances (whose shape groups it cannot see into) and no medium other than discrete ones
    (a forward-scattering fog's vertex is nearly a mirror)? Only then do an area light's penumbra and a surface's
    lobe blur the grains that a pixel receives: behind a mirror or a glass pane a ray is seen as sharply as a
    camera ray, grains in silhouette against a light included."""
    import mitsuba as mi

    allowed = int(mi.BSDFFlags.DiffuseReflection) | int(mi.BSDFFlags.DiffuseTransmission) | int(mi.BSDFFlags.Null)
    lobes = int(mi.BSDFFlags.All)
    for shape in scene.shapes():
        if shape.class_name() in ("Instance", "ShapeGroup"):
            return False
        bsdf = shape.bsdf() if hasattr(shape, "bsdf") else None
        if bsdf is None or int(bsdf.flags()) & lobes & ~allowed:
            return False
        for medium in (shape.interior_medium(), shape.exterior_medium()):
            if medium is not None and _scene.discrete_data(medium) is None and _scene.native_data(medium) is None:
                return False
    for sensor in scene.sensors():
        medium = getattr(sensor, "medium", lambda: None)()
        if medium is not None and _scene.discrete_data(medium) is None and _scene.native_data(medium) is None:
            return False
    return True


def attach(scene, sensor=None, integrator=None, spp: int = 0) -> list:
    """Set the scene's cameras (and ``sensor``'s, if the scene does not hold it) and the render's samples per pixel
    (``spp``, else the sensor's sampler's: ``samples_per_pixel``) on its discrete media, and what ``integrator``
    may skip around them (``motes.plugins.enclosure``; None: nothing). Returns the scene's ``discrete`` medium
    objects (``discrete_medium_objects``)."""
    if not _made[0] or not (hasattr(scene, "shapes") and hasattr(scene, "sensors")):
        return []
    _scene.fill_pending(scene)  # a scene loaded by loaders motes did not wrap (scene_checks.wrap_loaders)
    objects = _scene.discrete_medium_objects(scene)
    media = _scene.discrete_media(scene, objects)
    if media:
        enclosure.set_enclosures(scene, integrator, objects)
        cams, lights = cameras_of(scene, sensor), lights_of(scene)
        # A light the rule cannot place may be small and sharp: no blur then.
        diffuse = lights is not None and diffuse_only(scene) and uniform_distant_light(scene)
        samples = samples_per_pixel(scene, sensor, spp)
        for data in media:
            try:
                data.set_cameras(cams, lights, diffuse, samples)
            except ValueError as e:  # a camera or light the rule cannot use: rays from surfaces walk grains
                warnings.warn(f"motes: the scene's cameras or lights are not usable by the surface-ray rule ({e}); "
                              "rays from surfaces walk the grains", RuntimeWarning, stacklevel=3)
                data.set_cameras([], None)
    return objects


def _wrapped_render(render):
    if getattr(render, "_motes_cameras", False):
        return render

    @functools.wraps(render)
    def render_with_cameras(scene, *args, **kwargs):
        import mitsuba as mi

        sensor = kwargs.get("sensor", args[1] if len(args) > 1 else 0)
        integrator = kwargs.get("integrator", args[2] if len(args) > 2 else None)
        if not isinstance(integrator, mi.Integrator):
            integrator = scene.integrator() if hasattr(scene, "integrator") else None
        if not isinstance(sensor, mi.Sensor):
            sensors = list(scene.sensors()) if hasattr(scene, "sensors") else []
            sensor = sensors[sensor] if isinstance(sensor, int) and 0 <= sensor < len(sensors) else None
        spp = kwargs.get("spp", args[5] if len(args) > 5 else 0)
        objects = attach(scene, sensor, integrator, spp if isinstance(spp, int) else 0)
        try:
            return render(scene, *args, **kwargs)
        finally:
            if objects:  # a scene without discrete media is not scanned twice
                enclosure.clear_clips(scene, objects)

    render_with_cameras._motes_cameras = True
    return render_with_cameras


def wrap_render() -> None:
    """Make ``mi.render`` set the cameras first (once per process)."""
    import mitsuba as mi

    mi.render = _wrapped_render(mi.render)


__all__ = ["attach", "camera_of", "cameras_of", "data_of", "discrete_media", "discrete_medium_objects", "diffuse_only", "light_of", "lights_of", "uniform_distant_light",
           "wrap_render"]
