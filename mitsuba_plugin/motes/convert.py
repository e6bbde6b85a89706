"""``motes convert`` (issue 43): a Mitsuba 3 scene's ``homogeneous`` (and ``heterogeneous``) media rewritten as
``discrete``, with a report of everything that is not a 1:1 match.

    convert_scene(src, dst, medium=None, grains={"radius_median": "20"}) -> list of report lines

What it does to each converted medium (the module docs of ``motes.plugins.discrete_medium``, "From a homogeneous
medium", say why):

* ``type`` becomes ``discrete``; ``sigma_t``, ``scale``, ``albedo`` (float, rgb, spectrum; a ``constvolume``'s value),
  ``sample_emitters``, ``has_spectral_extinction`` and the phase child (``isotropic``, ``hg``, ``tabphase``,
  ``particle``) are kept; any other phase type is replaced by ``<phase type="particle"/>``; any other property is
  dropped. Mitsuba's defaults that ``discrete`` does not share are written out: ``sigma_t`` 1 (when neither it nor
  ``scale`` is given), ``albedo`` 0.75 and an ``isotropic`` phase function.
* the grain options (``GRAIN_OPTIONS``, typed as the plugin reads them) are added; a grain size (``radius_median``,
  ``psd`` or ``species``) is required.
* ``to_world``: none is written where every shape that holds the medium as its interior is one the grains fill
  (``FILLED_SHAPES``: closed meshes, ``cube``, ``sphere``, ``cylinder``): without ``to_world`` the discrete medium fills
  the shapes that hold it, their inside, as ``homogeneous`` does (a mesh that turns out open fails at load, naming
  itself). A given ``to_world`` is kept. Where a holder is of another type (``rectangle``, ``disk``, an instance...),
  the box of the holders is added instead, the grains filling that box: one ``cube`` holder gives its own transform
  (exact), anything else the union of the holders' world bounding boxes (Mitsuba loads each holder alone, in
  ``scalar_rgb``, file names relative to the scene's folder). Flat holders, holders whose geometry uses ``$``
  parameters and holders Mitsuba cannot load are reported and left out; with none left, to_world is the user's.
* ``heterogeneous``: a ``sigma_t`` gridvolume is kept as it is: the discrete medium takes it as the grains' number
  density, in the volume's own box (no ``to_world`` is written; "From a heterogeneous medium" in the plugin's docs);
  an albedo grid becomes its per-channel mean (a ``gridvolume``'s .vol file read by ``mi.VolumeGrid``). A volume
  that cannot be read leaves the medium unchanged (reported).

Everything else in the file is kept as it is (comments too; ``<default>`` and ``$name`` references untouched).
"""

from __future__ import annotations

import contextlib
import copy
import pathlib
import re
import xml.etree.ElementTree as ET

import numpy as np

#: Holder types whose inside the discrete medium fills without ``to_world`` (``motes.plugins.discrete_medium``, "Filling
#: the shapes that hold it"): meshes (closed ones) and Mitsuba's analytic sphere and cylinder.
FILLED_SHAPES = ("obj", "ply", "serialized", "cube", "sphere", "cylinder")

#: The grain options of ``motes convert``: (option, the discrete medium's parameter, its XML tag as
#: ``_read_parameters`` reads it, help).
GRAIN_OPTIONS = (
    ("--radius-median", "radius_median", "float", "log-normal median radius, um (required unless the medium has a "
                                                  "grain size, or with --psd / --species)"),
    ("--radius-sigma-g", "radius_sigma_g", "float", "log-normal geometric standard deviation (>= 1)"),
    ("--psd", "psd", "string", "a PSD as JSON, instead of the two above"),
    ("--species", "species", "string", "a JSON list of species (mixtures)"),
    ("--material", "material", "string", "ice or water (tabulated index), or --eta"),
    ("--eta", "eta", "float", "the grains' refractive index, real part"),
    ("--eta-k", "eta_k", "float", "the grains' refractive index, imaginary part"),
    ("--eta-medium", "eta_medium", "float", "index of the host medium"),
    ("--scale-m", "scale_m", "float", "metres per scene unit (the medium's default: 1e-3)"),
    ("--storage", "storage", "string", "compact, full or procedural"),
    ("--distribution", "distribution", "string", "uniform, gradient or noise"),
    ("--query-radius", "query_radius", "float", "query cylinder radius, scene units"),
    ("--continuous-count", "continuous_count", "float", "grains per query cylinder above which a size class is "
                                                        "continuous (inf: every grain walked)"),
    ("--size-bins", "size_bins", "integer", "radius bins of the optics tables"),
    ("--method", "method", "string", "auto, mie, goa or hybrid"),
    ("--seed", "seed", "integer", "seed of the grains' positions and free flights"),
)

#: Every other parameter of the discrete medium that ``--param NAME=VALUE`` may set, with its XML tag.
OTHER_PARAMETERS = {"count": "integer", "footprint_k": "float", "fov": "float",
                    "film_width": "integer", "z_med": "float", "tau_max": "float", "cells_per_particle": "float",
                    "grain_depth": "integer", "surface_footprint": "boolean", "cache_mb": "float",
                    "truncate_below": "float", "wavelengths": "string", "time": "float", "velocity": "vector",
                    "turbulence": "float", "turbulence_scale": "float", "wrap": "boolean", "phase_model": "string",
                    "filename": "string"}

#: XML tag of each parameter the converter writes.
PARAMETER_TAGS = {name: tag for _, name, tag, _ in GRAIN_OPTIONS} | OTHER_PARAMETERS

CONVERTED = ("homogeneous", "heterogeneous")
#: The phase functions a discrete medium takes (its module docs).
PHASES = ("particle", "isotropic", "hg", "tabphase")
#: What a homogeneous medium takes and the discrete medium takes alike.
SHARED = ("sigma_t", "scale", "albedo", "sample_emitters", "has_spectral_extinction")
GRAIN_SIZE = ("radius_median", "psd", "species")
#: Children of a shape that say nothing about its geometry (left out when Mitsuba loads it alone).
NOT_GEOMETRY = ("bsdf", "medium", "ref", "emitter", "sensor", "phase", "texture")


class ConvertError(ValueError):
    """A problem with the input that stops the conversion: one line for the user."""


def convert_scene(src, dst, medium: str | None = None, grains: dict | None = None) -> list[str]:
    """Rewrite ``src``'s homogeneous and heterogeneous media (or only ``medium``, an id or name) as discrete,
    with the parameters ``grains`` (name -> value as text) added, to ``dst``. Returns the report, one line per
    medium followed by one indented line per property that was not a 1:1 match."""
    src = pathlib.Path(src)
    text, root = _parse(src)
    grains = _typed(grains or {})
    doc = _Document(root, src.parent)
    report: list[str] = []
    for m in _selected(doc, medium, src):
        report += _Conversion(doc, m, grains).run()
    pathlib.Path(dst).write_text(_written(text, root))
    return report


def _written(text: str, root) -> str:
    """The converted tree as text, with the original's prolog (XML declaration, comments, DOCTYPE before
    ``<scene>``) and epilog, and its style of empty elements (``<a/>`` or ``<a />``)."""
    start = next(m.start() for m in _MARKUP.finditer(text) if m.group(0).startswith("<scene"))
    end = text.rfind("</scene>")
    epilog = text[end + len("</scene>"):] if end >= 0 else "\n"
    out = ET.tostring(root, encoding="unicode")
    if text.count(" />") < text.count("/>") / 2:  # ElementTree writes "<a />": back to the file's "<a/>"
        out = "".join(part if part.startswith("<!--") else part.replace(" />", "/>")
                      for part in re.split(r"(<!--.*?-->)", out, flags=re.S))
    return text[:start] + out + (epilog or "\n")


#: Comments, processing instructions, DOCTYPE and the root's start tag, to find where the root begins.
_MARKUP = re.compile(r"<!--.*?-->|<\?.*?\?>|<!DOCTYPE[^>]*>|<scene\b", re.S)


# -- Input ---------------------------------------------------------------------------------------------------------
def _parse(src: pathlib.Path):
    try:
        text = src.read_text()
    except OSError as e:
        raise ConvertError(f"cannot read {src}: {e.strerror or e}") from None
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True, insert_pis=True))
    try:
        root = ET.fromstring(text, parser=parser)
    except ET.ParseError as e:
        raise ConvertError(f"{src} is not valid XML: {e}") from None
    if root.tag != "scene":
        raise ConvertError(f"{src} is not a Mitsuba scene (its root element is <{root.tag}>, not <scene>)")
    return text, root


def _typed(grains: dict) -> dict:
    """``grains`` (parameter -> value as text) checked against the discrete medium's parameters and typed."""
    out = {}
    for name, value in grains.items():
        tag = PARAMETER_TAGS.get(name)
        if tag is None:
            raise ConvertError(f"--param {name}: not a parameter the converter sets; it sets "
                               + ", ".join(sorted(PARAMETER_TAGS)))
        value = str(value).strip()
        if "$" not in value:
            try:
                if tag == "float":
                    float(value)
                elif tag == "integer":
                    int(value)
                elif tag == "boolean" and value.lower() not in ("true", "false"):
                    raise ValueError
            except ValueError:
                raise ConvertError(f"{name} = {value!r}: the discrete medium reads it as <{tag}>") from None
        out[name] = (tag, value)
    return out


class _Document:
    """The parsed scene: its elements' parents, media by id and the scene's folder."""

    def __init__(self, root, folder: pathlib.Path):
        self.root, self.folder = root, folder
        self.parent = {c: p for p in root.iter() for c in p}
        self.by_id = {e.get("id"): e for e in root.iter() if e.get("id") is not None}

    def label(self, m) -> str:
        if m.get("id"):
            return m.get("id")
        parent = self.parent.get(m)
        where = f'{parent.tag} {_shape_label(self, parent)}' if parent is not None else "the scene"
        return f"{m.get('name') or 'unnamed'} of {where}"


def _shape_label(doc: _Document, shape) -> str:
    if shape.get("id"):
        return f'"{shape.get("id")}"'
    same = [s for s in doc.root.iter(shape.tag)]
    return f"#{same.index(shape) + 1} ({shape.get('type')})"


def _selected(doc: _Document, medium: str | None, src) -> list:
    media = list(doc.root.iter("medium"))
    if medium is not None:
        picked = [m for m in media if medium in (m.get("id"), m.get("name"))]
        if not picked:
            names = ", ".join(sorted({m.get("id") or m.get("name") or "?" for m in media})) or "none"
            raise ConvertError(f"--medium {medium}: no medium with that id or name in {src} (its media: {names})")
        wrong = [m for m in picked if m.get("type") not in CONVERTED]
        if wrong:
            raise ConvertError(f"--medium {medium}: a {wrong[0].get('type')} medium; motes convert converts "
                               + " and ".join(CONVERTED) + " media")
        return picked
    picked = [m for m in media if m.get("type") in CONVERTED]
    if not picked:
        raise ConvertError(f"no homogeneous or heterogeneous medium in {src}")
    return picked


# -- One medium ----------------------------------------------------------------------------------------------------
class _Conversion:
    """One medium's conversion: ``run()`` rewrites it in place and returns its report lines."""

    def __init__(self, doc: _Document, m, grains: dict):
        self.doc, self.m, self.grains = doc, m, grains
        self.kind = m.get("type")
        self.name = doc.label(m)
        self.kept: list[str] = []
        self.added: list[str] = []
        self.notes: list[str] = []
        self.to_world_note = ""

    def run(self) -> list[str]:
        volumes = {}
        if self.kind == "heterogeneous":
            volumes, problem = _volume_means(self.doc, self.m)
            if problem:
                return [f"medium {self.name} (heterogeneous): left unchanged: {problem}"]
        if not any(_prop(self.m, k) is not None for k in GRAIN_SIZE) and not any(k in self.grains for k in GRAIN_SIZE):
            raise ConvertError(f"--radius-median is required: medium {self.name} has no grain size "
                               "(radius_median, psd or species)")
        self.m.set("type", "discrete")
        self._properties(volumes)
        self._phase()
        self._defaults()
        self._grains()
        self._to_world()
        head = f"medium {self.name} ({self.kind} -> discrete): kept {', '.join(self.kept) or 'nothing'}"
        if self.added:
            head += f"; added {', '.join(self.added)}"
        head += f"; to_world {self.to_world_note}"
        return [head] + [f"  {n}" for n in self.notes]

    # The medium's own properties.
    def _properties(self, volumes: dict) -> None:
        for child in [c for c in self.m if isinstance(c.tag, str) and c.get("name") is not None and c.tag != "phase"
                      and not (c.tag == "ref" and _ref_tag(self.doc, c) == "phase")]:
            name = child.get("name")
            if name in volumes:
                self._replace(child, volumes[name][0])
                self.notes.append(volumes[name][1])
                self.kept.append(f"{name} (changed)")
            elif child.tag == "volume":
                self._volume_property(child, name)
            elif name in SHARED or name == "to_world" or name in PARAMETER_TAGS:
                self.kept.append(name)
                if name == "has_spectral_extinction":
                    self.notes.append("has_spectral_extinction: accepted and ignored by discrete (grey free "
                                      f"flights; it was {child.get('value')})")
            elif child.tag == "ref":
                self.kept.append(f"{name} (a reference)")
                self.notes.append(f"{name}: a <ref> kept as it is; check that discrete takes it")
            else:
                self.m.remove(child)
                self.notes.append(f"{name}: dropped: not a parameter of the discrete medium")

    def _volume_property(self, child, name: str) -> None:
        value = [c for c in child if isinstance(c.tag, str) and c.get("name") == "value"]
        if name == "sigma_t" and child.get("type") == "gridvolume":
            self.kept.append("sigma_t (a gridvolume)")
            self.notes.append("sigma_t: the gridvolume is the grains' number density, in its own box (its to_world)")
            return
        if child.get("type") == "constvolume" and len(value) == 1 and name in ("sigma_t", "albedo"):
            v = copy.deepcopy(value[0])
            v.set("name", name)
            self._replace(child, v)
            self.kept.append(name)
            self.notes.append(f"{name}: a constvolume: written as its value <{v.tag}>")
        else:
            self.m.remove(child)
            self.notes.append(f"{name}: dropped: a <volume type=\"{child.get('type')}\"> the discrete medium cannot "
                              "take")

    def _replace(self, old, new) -> None:
        i = list(self.m).index(old)
        new.tail = old.tail
        self.m.remove(old)
        self.m.insert(i, new)

    def _phase(self) -> None:
        phases = [c for c in self.m if c.tag == "phase" or (c.tag == "ref" and _ref_tag(self.doc, c) == "phase")]
        for p in phases:
            target = self.doc.by_id.get(p.get("id")) if p.tag == "ref" else p
            kind = target.get("type") if target is not None else "?"
            if kind in PHASES:
                self.kept.append(f"phase {kind}")
            else:
                new = ET.Element("phase", {"type": "particle"})
                self._replace(p, new)
                self.notes.append(f'phase {kind}: the discrete medium takes {", ".join(PHASES)}: replaced by '
                                  '<phase type="particle"/> (the grains\' own phase function)')
        if not phases:
            self._add("phase", {"type": "isotropic"})
            self.added.append("phase isotropic")
            self.notes.append('phase: none given: Mitsuba\'s default, isotropic, written out (remove it for the '
                              "grains' own phase function)")

    def _defaults(self) -> None:
        """homogeneous's defaults that discrete does not share, written out."""
        if _prop(self.m, "sigma_t") is None and _prop(self.m, "scale") is None:
            self._add("float", {"name": "sigma_t", "value": "1"})
            self.added.append("sigma_t 1")
            self.notes.append(f"sigma_t: none given: {self.kind}'s default, 1, written out (discrete's default is "
                              "count = 10000 grains)")
        if _prop(self.m, "albedo") is None:
            self._add("float", {"name": "albedo", "value": "0.75"})
            self.added.append("albedo 0.75")
            self.notes.append(f"albedo: none given: {self.kind}'s default, 0.75, written out (remove it for the "
                              "grains' own, physical albedo)")

    def _grains(self) -> None:
        for name, (tag, value) in self.grains.items():
            old = _prop(self.m, name)
            new = ET.Element(tag, {"name": name, "value": value})
            if old is not None:
                self.notes.append(f"{name}: {old.get('value')} replaced by {value} (command line)")
                self._replace(old, new)
            else:
                self._add_element(new)
            self.added.append(f"{name} {value}")

    def _to_world(self) -> None:
        if _prop(self.m, "to_world") is not None:
            self.to_world_note = "kept (given)"
            return
        sigma_t = _prop(self.m, "sigma_t")
        if sigma_t is not None and sigma_t.tag == "volume" and sigma_t.get("type") == "gridvolume":
            self.to_world_note = "not needed: the sigma_t grid places the grains (its own to_world)"
            return
        holders, others = _holders(self.doc, self.m)
        if holders and all(shape.get("type") in FILLED_SHAPES for shape in holders):
            names = ", ".join(_shape_label(self.doc, s) for s in holders)
            self.to_world_note = f"not needed: the grains fill the shape{'s' if len(holders) > 1 else ''} {names}"
            for where in others:
                self.notes.append(f"to_world: the medium is also {where}: the grains fill only the shapes whose "
                                  "interior it is")
            return
        for where in others:
            self.notes.append(f"to_world: the medium is also {where}: the grains fill only their box (to_world)")
        boxes = []
        for shape in holders:
            box, problem = _world_box(self.doc, shape)
            if problem:
                self.notes.append(f"to_world: shape {_shape_label(self.doc, shape)} ({shape.get('type')}) left "
                                  f"out: {problem}")
            else:
                boxes.append((shape, box))
        if not boxes:
            self.to_world_note = "NOT set (no holding shape to take it from: set it to the region the grains fill)"
            self.notes.append("to_world: not set: " + ("no shape holds this medium as its interior; the grains fill "
                              "the cube [-1, 1]^3 until it is set" if not holders else "no holding shape's box could "
                              "be computed, and a holder's type has no inside the grains can fill: the scene "
                              "loads once to_world is set"))
            return
        self._add_element(self._transform_of(boxes))

    def _transform_of(self, boxes):
        t = ET.Element("transform", {"name": "to_world"})
        if len(boxes) == 1 and boxes[0][1][2] is not None:  # one cube: its own transform, exact
            matrix = boxes[0][1][2]
            ET.SubElement(t, "matrix", {"value": " ".join(_num(v) for v in matrix.ravel())})
            self.to_world_note = f"= the own transform of cube {_shape_label(self.doc, boxes[0][0])}"
            return t
        lo = np.min([b[0] for _, b in boxes], axis=0)
        hi = np.max([b[1] for _, b in boxes], axis=0)
        ET.SubElement(t, "scale", {"value": ", ".join(_num(v) for v in (hi - lo) / 2)})
        ET.SubElement(t, "translate", {"value": ", ".join(_num(v) for v in (hi + lo) / 2)})
        names = ", ".join(_shape_label(self.doc, s) for s, _ in boxes)
        self.to_world_note = f"= the box [{_vec(lo)}] - [{_vec(hi)}] of shape{'s' if len(boxes) > 1 else ''} {names}"
        if len(boxes) > 1 or boxes[0][0].get("type") != "cube":
            self.notes.append("to_world: the holders' world bounding box: the grains fill the box, the shapes cut "
                              "what is seen (grains outside every holder are never met)")
        return t

    # Placing new elements where they read well: before the phase child, indented as their siblings.
    def _add(self, tag: str, attrib: dict) -> None:
        self._add_element(ET.Element(tag, attrib))

    def _add_element(self, e) -> None:
        kids = [c for c in self.m]
        indent = self.m.text if kids and self.m.text and not self.m.text.strip() else ""  # "": one line
        phase = next((i for i, c in enumerate(kids) if c.tag == "phase"), None)
        if phase is not None and e.tag != "phase":
            e.tail = indent
            self.m.insert(phase, e)
            return
        if kids:
            e.tail = kids[-1].tail
            kids[-1].tail = indent
        self.m.append(e)


def _prop(m, name: str):
    return next((c for c in m if isinstance(c.tag, str) and c.get("name") == name), None)


def _ref_tag(doc: _Document, ref):
    target = doc.by_id.get(ref.get("id"))
    return target.tag if target is not None else None


def _num(v: float) -> str:
    v = float(v)
    return "0" if abs(v) < 1e-12 else f"{v:.7g}"


def _vec(v) -> str:
    return ", ".join(f"{float(x):.4g}" for x in v)


# -- Where the medium is -------------------------------------------------------------------------------------------
def _holders(doc: _Document, m):
    """(the shapes that hold ``m`` as their interior, descriptions of its other uses: exterior, the sensor's)."""
    holders, others = [], []
    parent = doc.parent.get(m)
    if parent is not None and parent.tag == "shape" and m.get("name") == "interior":
        holders.append(parent)
    elif parent is not None and parent.tag == "shape":
        others.append(f"the {m.get('name') or 'unnamed'} medium of shape {_shape_label(doc, parent)}")
    elif parent is not None and parent.tag == "sensor":
        others.append("the sensor's medium (the camera sits in it)")
    mid = m.get("id")
    if mid:
        for ref in doc.root.iter("ref"):
            owner = doc.parent.get(ref)
            if ref.get("id") != mid or owner is None or owner is m:
                continue
            if owner.tag == "shape" and ref.get("name") == "interior":
                holders.append(owner)
            elif owner.tag == "shape":
                others.append(f"the {ref.get('name') or 'unnamed'} medium of shape {_shape_label(doc, owner)}")
            elif owner.tag == "sensor":
                others.append("the sensor's medium (the camera sits in it)")
    return holders, others


@contextlib.contextmanager
def _scalar_mitsuba(folder: pathlib.Path):
    """Mitsuba in ``scalar_rgb`` with the scene's folder first on the file resolver; both restored after."""
    import mitsuba as mi  # noqa: PLC0415

    before = mi.variant()
    mi.set_variant("scalar_rgb")
    saved = mi.FileResolver(mi.file_resolver())
    resolver = mi.FileResolver(saved)
    resolver.prepend(str(folder.resolve()))
    mi.Thread.thread().set_file_resolver(resolver)
    try:
        yield mi
    finally:
        mi.Thread.thread().set_file_resolver(saved)
        if before and before != "scalar_rgb":
            mi.set_variant(before)


def _geometry(shape, keep_transform: bool = True):
    """A copy of ``shape`` without what does not describe its geometry (bsdf, media, references, emitters)."""
    g = copy.deepcopy(shape)
    for c in list(g):
        if not isinstance(c.tag, str) or c.tag in NOT_GEOMETRY or (c.tag == "transform" and not keep_transform):
            g.remove(c)
    g.attrib.pop("id", None)
    return g


def _load_alone(doc: _Document, mi, shape):
    scene = ET.Element("scene", {"version": doc.root.get("version", "3.0.0")})
    scene.extend(copy.deepcopy(d) for d in doc.root if d.tag == "default")
    scene.append(shape)
    return mi.load_string(ET.tostring(scene, encoding="unicode")).shapes()[0]


def _world_box(doc: _Document, shape):
    """((lo, hi, the cube's local-to-world 4x4 or None), None) or (None, why not)."""
    g = _geometry(shape)
    params = sorted({"$" + p for e in g.iter() for v in e.attrib.values() for p in re.findall(r"\$(\w+)", v)})
    if params:
        return None, f"its geometry uses scene parameters ({', '.join(params)}): set to_world by hand"
    try:
        with _scalar_mitsuba(doc.folder) as mi:
            loaded = _load_alone(doc, mi, g)
            bbox = loaded.bbox()
            lo, hi = np.array(bbox.min, dtype=float), np.array(bbox.max, dtype=float)
            matrix = _cube_matrix(doc, mi, shape, loaded) if shape.get("type") == "cube" else None
    except Exception as e:  # noqa: BLE001 - whatever Mitsuba says, the holder is reported and left out
        return None, "Mitsuba could not load it alone: " + " ".join(str(e).split())[:200]
    extent = hi - lo
    if not np.all(np.isfinite(extent)) or extent.min() <= 1e-6 * max(extent.max(), 1e-30):
        return None, "flat (it holds no volume)"
    return (lo, hi, matrix), None


def _cube_matrix(doc: _Document, mi, shape, loaded):
    """The cube's local-to-world transform, fitted from its vertices with and without its transform."""
    plain = _load_alone(doc, mi, _geometry(shape, keep_transform=False))
    local = np.array(mi.traverse(plain)["vertex_positions"], dtype=float).reshape(-1, 3)
    world = np.array(mi.traverse(loaded)["vertex_positions"], dtype=float).reshape(-1, 3)
    a = np.column_stack([local, np.ones(len(local))])
    fit, *_ = np.linalg.lstsq(a, world, rcond=None)
    m = np.eye(4)
    m[:3, :] = fit.T
    if not np.allclose(a @ fit, world, atol=1e-4 * max(1.0, np.abs(world).max())):
        return None  # not affine (cannot happen for Mitsuba's cube): the bounding box instead
    return m


# -- Heterogeneous media -------------------------------------------------------------------------------------------
def _volume_means(doc: _Document, m):
    """({"sigma_t" / "albedo": (the element that replaces the volume, a report line)}, problem or None)."""
    out = {}
    for name in ("sigma_t", "albedo"):
        v = _prop(m, name)
        if v is None or v.tag != "volume" or v.get("type") != "gridvolume":
            continue
        f = _prop(v, "filename")
        path = f.get("value") if f is not None else None
        if path is None or "$" in path:
            return {}, f"its {name} gridvolume's filename {'uses a scene parameter' if path else 'is not given'}"
        try:
            with _scalar_mitsuba(doc.folder):
                import mitsuba as mi  # noqa: PLC0415

                grid = np.array(mi.VolumeGrid(str(mi.file_resolver().resolve(path))), dtype=float)
        except Exception as e:  # noqa: BLE001
            return {}, f"its {name} grid {path} could not be read: " + " ".join(str(e).split())[:160]
        grid = grid.reshape(-1, grid.shape[-1]) if grid.ndim == 4 else grid.reshape(-1, 1)
        if name == "sigma_t":
            continue  # kept as it is (_Conversion._volume_property): the grains' density
        else:
            means = grid.mean(axis=0)
            e = (ET.Element("rgb", {"name": name, "value": ", ".join(_num(x) for x in means)}) if means.size == 3
                 else ET.Element("float", {"name": name, "value": _num(means.mean())}))
            line = f"albedo: the mean of the grid {path} ({e.get('value')}), uniform"
        out[name] = (e, line)
    return out, None
