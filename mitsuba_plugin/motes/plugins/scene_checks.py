"""Checks of a loaded scene that catch silent mistakes with ``discrete`` media.

A ``discrete`` medium without ``to_world`` or particle file fills the shapes that hold it (checked by
construction: no warning). One with them takes its particle positions in scene units, after its own ``to_world``;
the shape that holds it has a separate ``to_world``. A medium with a ``to_world`` that maps its local cube [-1, 1]^3 onto
its holders' box (a mesh's own transform does not), or a particle file in other units, puts the particles
outside the shape, and the render shows an empty medium without a
word. After every ``mi.load_file`` / ``mi.load_dict`` / ``mi.load_string`` (wrapped once per process by
``wrap_loaders``; ``motes render`` goes through them too), ``check_scene`` compares, for each shape with a
``discrete`` interior medium, the box of the particles' centres with the shape's bounding box (for a medium
that several shapes share, the box around theirs), and warns when less than ``INSIDE_WARN_SHARE`` of the
particles' box lies inside it. A scene whose plugin
rejects its parameters raises Mitsuba's RuntimeError (where in the scene) with the plugin's message and
without its Python traceback (``motes._errors``).
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from .._errors import without_traceback
from . import cameras
from ._scene import discrete_data, fill_pending

#: Below this share of the particles' box inside the shape's box, loading warns.
INSIDE_WARN_SHARE = 0.5


def inside_share(lo, hi, shape_lo, shape_hi) -> float:
    """Share of the box [lo, hi] (its volume; along a flat axis, whether it lies in range) inside
    [shape_lo, shape_hi]."""
    share = 1.0
    for a, b, c, d in zip(lo, hi, shape_lo, shape_hi):
        if b > a:
            share *= max(0.0, min(b, d) - max(a, c)) / (b - a)
        else:
            share *= float(c <= a <= d)
    return share


def _fmt(v) -> str:
    return "(" + ", ".join(f"{float(x):.4g}" for x in v) + ")"


def _box_transform(lo, hi) -> str:
    """The XML of the transform that maps the cube [-1, 1]^3 onto the box [lo, hi] (scale, then translate)."""
    half, centre = (hi - lo) / 2, (hi + lo) / 2
    return (f'<transform name="to_world"><scale value="{_fmt(half)[1:-1]}"/>'
            f'<translate value="{_fmt(centre)[1:-1]}"/></transform>')


def outside_warnings(scene) -> list[str]:
    """A message for each ``discrete`` medium whose particles lie mostly outside the shape that holds it (the
    shapes, where several share it: the box around theirs)."""
    out, holders = [], {}  # id(data) -> (medium, data, [shapes])
    for shape in scene.shapes():
        medium = shape.interior_medium()
        data = None if medium is None else discrete_data(medium)
        if data is not None and not getattr(data, "fills_holders", False):  # a filled medium lies in them
            holders.setdefault(id(data), (medium, data, []))[2].append(shape)
    for medium, data, shapes in holders.values():
        lo, hi = (np.asarray(v, dtype=np.float64) for v in data.centre_box)
        boxes = [shape.bbox() for shape in shapes]
        s_lo = np.min([np.array(b.min, dtype=np.float64) for b in boxes], axis=0)
        s_hi = np.max([np.array(b.max, dtype=np.float64) for b in boxes], axis=0)
        share = inside_share(lo, hi, s_lo, s_hi)
        if share < INSIDE_WARN_SHARE:
            names = ", ".join(repr(shape.id() or "(unnamed)") for shape in shapes)
            which, boxes_of = ((f"the shape {names} that holds it", "shape's") if len(shapes) == 1 else
                               (f"the shapes {names} that hold it", "shapes'"))
            out.append(
                f"motes: the discrete medium {medium.id() or '(unnamed)'!r} lies mostly outside {which} "
                f"({share:.0%} of the particles' box inside; "
                f"particles' box {_fmt(lo)}..{_fmt(hi)}, {boxes_of} box "
                f"{_fmt(s_lo)}..{_fmt(s_hi)}, scene units), so "
                "the render will show little or none of it: remove the medium's to_world (without one its grains fill "
                "the shapes that hold it), or give it the to_world that maps its local cube "
                f"[-1, 1]^3 onto the {boxes_of} box, {_box_transform(s_lo, s_hi)} (for a cube or sphere of your own, "
                "the shape's to_world works too; a mesh's own to_world does not: its vertices are not in [-1, 1]^3; "
                "`motes convert` writes it), or check the particle file's units")
    return out


def check_scene(scene, stacklevel: int = 2) -> None:
    for message in outside_warnings(scene):
        warnings.warn(message, RuntimeWarning, stacklevel=stacklevel + 1)


def _wrapped(load):
    if getattr(load, "_motes_checked", False):
        return load

    @functools.wraps(load)
    def load_and_check(*args, **kwargs):
        try:
            obj = load(*args, **kwargs)
        except RuntimeError as e:
            # A plugin's invalid parameters: Mitsuba's message (where in the scene) and the plugin's, without
            # the plugin's Python traceback (motes._errors).
            clean = without_traceback(str(e))
            if clean is None:
                raise
            raise RuntimeError(clean) from None
        # Media that fill the shapes holding them get their grains now (_scene.fill_pending): a problem with the
        # holders (an open mesh) is the loader's error.
        fill_pending(obj)
        if hasattr(obj, "shapes") and hasattr(obj, "sensors"):  # a scene (load_dict also makes plugins)
            check_scene(obj, stacklevel=3)
            cameras.attach(obj)  # the surface-ray rule's cameras (cameras.py)
        return obj

    load_and_check._motes_checked = True
    return load_and_check


def wrap_loaders() -> None:
    """Make Mitsuba's scene loaders run ``check_scene`` and set the scene's cameras on its discrete media
    (``cameras.attach``; once per process: the loaders are shared by all variants)."""
    import mitsuba as mi

    for name in ("load_file", "load_dict", "load_string"):
        fn = getattr(mi, name, None)
        if fn is not None:
            setattr(mi, name, _wrapped(fn))


__all__ = ["INSIDE_WARN_SHARE", "check_scene", "inside_share", "outside_warnings", "wrap_loaders"]
