"""A scene's ``discrete`` media: from a Mitsuba medium object to its data (``motes.DiscreteMedium``), for the
Python plugin's objects and the native ones (``motes.native``) alike, and the scan of a scene's shapes and sensors
for them.

A ``discrete`` medium without ``to_world`` or particle file fills the shapes that hold it, which Mitsuba builds
after the medium: until its scene has loaded it is a ``PendingFill`` (``discrete_medium``'s docs, "Filling the shapes
that hold it"), and ``fill_pending`` hands each such medium its holders after every load.

The one lookup the plugin modules share: ``cameras``, ``enclosure``, ``scene_checks`` and ``discrete_medium`` all
import it, and it imports none of them (issue 42's layering: ``scripts/check_layers.py``).
"""

from __future__ import annotations

import itertools
import weakref

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
    """The data of a native ``discrete`` medium object (scalar variants' scene media), or None (also while it waits
    for its holders: ``PendingFill``)."""
    handle = native.medium_handle(medium)
    owner = None if handle is None else _motes.native_owner(handle)
    return owner if isinstance(owner, DiscreteMedium) else None


#: The ``PendingFill`` objects not yet filled (``fill_pending`` scans a scene only while there are any).
_UNFILLED: weakref.WeakSet = weakref.WeakSet()


class PendingFill:
    """A ``discrete`` medium whose grains fill the shapes that hold it, known once its scene has loaded. ``make(shapes)``
    builds its data (``motes.DiscreteMedium``) from those shapes (none: a medium that no shape holds); ``handles``
    are the pending native handles (``_motes.native_pending_handle``) its native medium and phase function were
    made over, given the data's core then. It holds no Mitsuba object (the native handles own it)."""

    def __init__(self, make, handles=()):
        self._make = make
        self.handles = list(handles)
        self.data: DiscreteMedium | None = None
        _UNFILLED.add(self)

    def fill(self, shapes) -> DiscreteMedium:
        """Build the data from the holding ``shapes`` (once; later calls return it)."""
        if self.data is None:
            data = self._make(list(shapes))
            for handle in self.handles:
                data.core.native_fill(handle, data)
            self.data, self._make = data, None
            _UNFILLED.discard(self)
        return self.data

    def result(self) -> DiscreteMedium:
        """The data: filled, or made now for a medium no shape holds (``fill([])``)."""
        return self.data if self.data is not None else self.fill([])


def pending_of(medium) -> PendingFill | None:
    """The ``PendingFill`` of a ``discrete`` medium object (Python or native) that waits for its holders, or None."""
    if medium is None:
        return None
    pending = getattr(medium, "_motes_pending", None)
    if pending is None:
        handle = native.medium_handle(medium)
        pending = None if handle is None else _motes.native_owner(handle)
    return pending if isinstance(pending, PendingFill) and pending.data is None else None


def fill_pending(obj) -> None:
    """Fill every ``discrete`` medium of a loaded scene (or shape, or medium) that waits for its holders: each with
    the shapes whose interior it is, all of them; one that only an exterior or a sensor holds, or a medium loaded
    alone, with none (``PendingFill.fill``)."""
    if not _UNFILLED:
        return
    if hasattr(obj, "shapes") and hasattr(obj, "sensors"):
        shapes, others = list(obj.shapes()), [getattr(s, "medium", lambda: None)() for s in obj.sensors()]
    elif hasattr(obj, "interior_medium"):
        shapes, others = [obj], []
    else:
        shapes, others = [], [obj]
    groups: dict = {}
    for shape in shapes:
        if shape.is_medium_transition():
            pending = pending_of(shape.interior_medium())
            if pending is not None:
                groups.setdefault(id(pending), (pending, []))[1].append(shape)
            others.append(shape.exterior_medium())
    for pending, holders in groups.values():
        data = pending.fill(holders)
        for shape in holders:  # a native medium (scalar variants' scene object) says what it now holds
            native.set_description(shape.interior_medium(), data.summary())
    for medium in others:
        pending = pending_of(medium)
        if pending is not None:
            native.set_description(medium, pending.fill([]).summary())


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


__all__ = ["PendingFill", "data_of", "discrete_data", "discrete_media", "discrete_medium_objects", "fill_pending", "native_data",
           "pending_of"]
