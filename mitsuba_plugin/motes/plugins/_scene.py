"""A scene's ``discrete`` media: from a Mitsuba medium object to its data (``motes.DiscreteMedium``), for the
Python plugin's objects and the native ones (``motes.native``) alike, and the scan of a scene's shapes and sensors
for them.

The one lookup the plugin modules share: ``cameras``, ``enclosure``, ``scene_checks`` and ``discrete_medium`` all
import it, and it imports none of them (issue 42's layering: ``scripts/check_layers.py``).
"""

from __future__ import annotations

import itertools

from .. import _motes, native
from ..discrete import DiscreteMedium


def discrete_data(medium) -> DiscreteMedium | None:
    """The data of a medium object that carries it as ``data`` (the Python plugin's; native ones too once
    ``discrete_medium.install_native_accessors`` has run), or None for any other medium."""
    try:
        data = getattr(medium, "data", None)
    except Exception:  # noqa: BLE001 - a foreign medium's property may raise anything
        return None
    return data if isinstance(data, DiscreteMedium) else None


def native_data(medium) -> DiscreteMedium | None:
    """The data of a native ``discrete`` medium object (scalar variants' scene media), or None."""
    handle = native.medium_handle(medium)
    return None if handle is None else _motes.native_owner(handle)


def data_of(medium) -> DiscreteMedium | None:
    """The data of a ``discrete`` medium object (Python or native), or None."""
    if medium is None:
        return None
    return discrete_data(medium) or native_data(medium)


def discrete_medium_objects(scene) -> list:
    """Every ``discrete`` medium object the scene's shapes and sensors hold, each once. One pass over the
    shapes, each medium object looked at once: ``mi.render`` asks for them at every call, and a scene of
    5·10^5 spheres (explicit path tracing) spent 2.6 s per call in a pass that asked every shape's media
    for their data."""
    media, seen = [], set()
    shape_media = (m for s in scene.shapes() if s.is_medium_transition()
                   for m in (s.interior_medium(), s.exterior_medium()))
    sensor_media = (getattr(s, "medium", lambda: None)() for s in scene.sensors())
    for m in itertools.chain(shape_media, sensor_media):
        if m is not None and id(m) not in seen:
            seen.add(id(m))
            if data_of(m) is not None:
                media.append(m)
    return media


def discrete_media(scene, objects=None) -> list:
    """The data (``motes.DiscreteMedium``) of every ``discrete`` medium the scene's shapes and sensors hold (of
    ``objects``, the scene's ``discrete_medium_objects``, where the caller has them), each once."""
    objects = discrete_medium_objects(scene) if objects is None else objects
    return list({id(d): d for d in map(data_of, objects)}.values())


__all__ = ["data_of", "discrete_data", "discrete_media", "discrete_medium_objects", "native_data"]
