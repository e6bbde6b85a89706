"""``motes convert`` (issue 43): a scene's homogeneous media rewritten as discrete, with a report.

* two holders (a rotated ``cube`` and a transformed ``sphere``) sharing one homogeneous medium with an rgb albedo, an
  ``hg`` phase function and ``has_spectral_extinction``: the converted scene loads in ``scalar_rgb`` and renders; it
  has no ``to_world`` (the grains fill both holders, inside them); the report names ``has_spectral_extinction``;
* a holder the grains cannot fill (a rectangle): the holders' box as to_world; flat and parametrised holders, other
  phase types, heterogeneous grids: reported;
* ``--medium`` picks one medium of two; the rest of the file (comments too) is kept as it was;
* errors (missing or unparsable file, unknown ``--medium``, no medium to convert, no grain size) exit 2 with one line.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import motes
from _scenes import medium_xml, sensor_xml

mi = pytest.importorskip("mitsuba")

ROOT = pathlib.Path(__file__).resolve().parent.parent
GRAINS = ["--radius-median", "200", "--scale-m", "0.01", "--seed", "7"]

SCENE = """<?xml version="1.0" encoding="utf-8"?>
<!-- two holders share the fog; a crate holds the smoke -->
<scene version="3.0.0">
  <default name="spp" value="4"/>
  <integrator type="volpath"><integer name="max_depth" value="16"/></integrator>
""" + sensor_xml(45, "0, 0.5, 9") + """  <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
""" + medium_xml("homogeneous", [("float", "sigma_t", 0.5), ("float", "scale", 2), ("rgb", "albedo", "0.9, 0.6, 0.3"),
                            ("boolean", "has_spectral_extinction", "true")], '<phase type="hg"><float name="g" value="0.5"/></phase>',
                 'id="fog"', "  ", "the shared fog") + medium_xml("homogeneous", [("float", "sigma_t", 0.3)], '<phase type="rayleigh"/>',
                                                                   'id="smoke"', "  ") + """  <shape type="cube" id="left">
    <transform name="to_world"><scale value="0.5, 1, 0.5"/><rotate y="1" angle="30"/><translate value="-1.5, 0, 0"/></transform>
    <bsdf type="null"/><ref name="interior" id="fog"/>
  </shape>
  <shape type="sphere" id="right">
    <transform name="to_world"><scale value="0.8"/><translate value="1, 0.5, 0.2"/></transform>
    <bsdf type="null"/><ref name="interior" id="fog"/>
  </shape>
  <shape type="cube" id="crate">
    <transform name="to_world"><rotate x="1" angle="20"/><scale value="0.4"/><translate value="0, -2, 0"/></transform>
    <bsdf type="null"/><ref id="smoke" name="interior"/>
  </shape>
</scene>
"""


def run(*args):
    """``python -m motes`` with this worktree's package first on the path."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "mitsuba_plugin"), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "motes", *args], capture_output=True, text=True, timeout=300, env=env)


def convert(tmp_path, *args, scene: str | None = SCENE):
    """``motes convert`` of ``scene`` (written to ``tmp_path``; None: a file that is not there): (process, output)."""
    src, out = tmp_path / "scene.xml", tmp_path / "out.xml"
    if scene is not None:
        src.write_text(scene)
    return run("convert", str(src), "-o", str(out), *args), out


def medium(path: pathlib.Path, mid: str):
    return next(m for m in ET.parse(path).getroot().iter("medium") if mid in (m.get("id"), m.get("name")))


def prop(m, name):
    return next((c for c in m if c.get("name") == name), None)


def world_boxes(xml: str) -> dict:
    """Each shape's world bounding box, as Mitsuba loads the original scene."""
    motes.set_variant("scalar_rgb")
    scene = mi.load_string(xml)
    return {s.id(): (np.array(s.bbox().min), np.array(s.bbox().max)) for s in scene.shapes()}


def to_world_of(m) -> np.ndarray:
    """The 4x4 matrix of a converted medium's ``to_world`` (Mitsuba's reading of the XML)."""
    motes.set_variant("scalar_rgb")
    t = ET.tostring(prop(m, "to_world"), encoding="unicode")
    placed = mi.load_string(f'<scene version="3.0.0"><shape type="cube">{t}</shape></scene>').shapes()[0]
    plain = mi.load_string('<scene version="3.0.0"><shape type="cube"/></scene>').shapes()[0]
    local = np.array(mi.traverse(plain)["vertex_positions"]).reshape(-1, 3)
    world = np.array(mi.traverse(placed)["vertex_positions"]).reshape(-1, 3)
    fit, *_ = np.linalg.lstsq(np.column_stack([local, np.ones(len(local))]), world, rcond=None)
    return np.vstack([fit.T, [0, 0, 0, 1]])


@pytest.mark.filterwarnings("ignore:discrete medium. has_spectral_extinction = true is ignored")
def test_shared_medium_converts_loads_and_renders(tmp_path):
    proc, out = convert(tmp_path, *GRAINS)
    assert proc.returncode == 0, proc.stderr
    report = proc.stdout.splitlines()
    head = [ln for ln in report if ln.startswith("medium fog")]
    assert len(head) == 1 and "homogeneous -> discrete" in head[0] and '"left", "right"' in head[0], report
    assert "sigma_t" in head[0] and "albedo" in head[0] and "phase hg" in head[0]
    assert any("has_spectral_extinction" in ln and "ignored" in ln for ln in report), report
    assert any("phase rayleigh" in ln and "particle" in ln for ln in report), report  # smoke's phase
    fog = medium(out, "fog")
    assert fog.get("type") == "discrete" and medium(out, "smoke").get("type") == "discrete"
    assert prop(fog, "albedo").tag == "rgb" and prop(fog, "albedo").get("value") == "0.9, 0.6, 0.3"
    assert fog.find("phase").get("type") == "hg" and prop(fog, "radius_median").get("value") == "200"
    assert prop(fog, "seed").tag == "integer" and prop(fog, "scale_m").tag == "float"
    # No to_world: the grains fill the holders (issue 43); the report says so.
    assert prop(fog, "to_world") is None and prop(medium(out, "smoke"), "to_world") is None
    assert 'to_world not needed: the grains fill the shapes "left", "right"' in head[0], head
    # It loads with motes's plugins in scalar_rgb and renders at 16 px / 4 spp.
    motes.set_variant("scalar_rgb")
    scene = mi.load_file(str(out))
    media = {s.id(): s.interior_medium() for s in scene.shapes()}
    assert len(media["left"].data) > 100 and len(media["crate"].data) > 10
    assert media["left"].data.fills_holders and media["crate"].data.fills_holders
    # The grains lie in the holders' boxes (the fill's own tests: test_fill.py).
    boxes = world_boxes(SCENE)
    lo, hi = (np.asarray(v) for v in media["crate"].data.centre_box)
    assert np.all(lo >= boxes["crate"][0] - 1e-5) and np.all(hi <= boxes["crate"][1] + 1e-5)
    img = np.array(mi.render(scene, spp=4))
    assert img.shape[:2] == (16, 16) and np.all(np.isfinite(img)) and img.mean() > 0


def test_the_rest_of_the_file_is_kept(tmp_path):
    proc, out = convert(tmp_path, *GRAINS)
    assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    assert text.startswith('<?xml version="1.0" encoding="utf-8"?>\n<!-- two holders')
    assert "<!-- the shared fog -->" in text and '<default name="spp" value="4"/>' in text and '"$spp"' in text
    old, new = SCENE.splitlines(), text.splitlines()
    gone = [ln for ln in old if ln not in new]
    assert all('type="homogeneous"' in ln or 'type="rayleigh"' in ln for ln in gone), gone


def test_medium_picks_one_of_two(tmp_path):
    proc, out = convert(tmp_path, "--medium", "smoke", *GRAINS)
    assert proc.returncode == 0, proc.stderr
    heads = [ln for ln in proc.stdout.splitlines() if ln.startswith("medium ")]
    assert len(heads) == 1 and heads[0].startswith("medium smoke"), proc.stdout
    assert medium(out, "smoke").get("type") == "discrete" and medium(out, "fog").get("type") == "homogeneous"
    assert prop(medium(out, "fog"), "radius_median") is None
    # Mitsuba's defaults the discrete medium does not share are written out, and said.
    smoke = medium(out, "smoke")
    assert prop(smoke, "albedo").get("value") == "0.75" and smoke.find("phase").get("type") == "particle"
    assert any(ln.strip().startswith("albedo: none given") for ln in proc.stdout.splitlines())


FLAT = """<scene version="3.0.0">
  <default name="h" value="2"/>
  <shape type="rectangle" id="floor"><ref name="interior" id="fog"/></shape>
  <shape type="cube" id="tower"><transform name="to_world"><scale value="1, $h, 1"/></transform><ref name="interior" id="fog"/></shape>
  <medium type="homogeneous" id="fog"><float name="sigma_t" value="1"/></medium>
</scene>
"""


def test_flat_and_parametrised_holders_are_reported(tmp_path):
    proc, out = convert(tmp_path, *GRAINS, scene=FLAT)
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert 'shape "floor" (rectangle) left out: flat' in text
    assert 'shape "tower" (cube) left out: its geometry uses scene parameters ($h)' in text
    assert "to_world NOT set" in text and prop(medium(out, "fog"), "to_world") is None
    assert "the scene loads once to_world is set" in text


RECTANGLE = """<scene version="3.0.0">
  <shape type="rectangle" id="pane"><transform name="to_world"><translate value="0, 0, 3"/></transform><ref name="interior" id="fog"/></shape>
  <shape type="cube" id="box"><ref name="interior" id="fog"/></shape>
  <medium type="homogeneous" id="fog"><float name="sigma_t" value="1"/></medium>
</scene>
"""


def test_a_holder_without_an_inside_gets_the_box(tmp_path):
    """A rectangle among the holders: the grains cannot fill it, so the box of the holders is written (the cube's
    here: the flat pane is left out)."""
    proc, out = convert(tmp_path, *GRAINS, scene=RECTANGLE)
    assert proc.returncode == 0, proc.stderr
    assert 'shape "pane" (rectangle) left out: flat' in proc.stdout
    assert np.allclose(to_world_of(medium(out, "fog")), np.eye(4), atol=1e-5)


def test_heterogeneous_keeps_its_grid(tmp_path):
    motes.set_variant("scalar_rgb")
    grid = np.random.default_rng(1).uniform(0, 2, (4, 5, 6, 1)).astype(np.float32)
    mi.VolumeGrid(grid).write(str(tmp_path / "density.vol"))
    scene = """<scene version="3.0.0">
  <shape type="sphere" id="puff"><float name="radius" value="2"/><bsdf type="null"/>
    <medium type="heterogeneous" name="interior">
      <volume name="sigma_t" type="gridvolume"><string name="filename" value="density.vol"/></volume>
      <float name="scale" value="3"/>
      <phase type="isotropic"/>
    </medium>
  </shape>
  <medium type="heterogeneous" id="lost">
    <volume name="sigma_t" type="gridvolume"><string name="filename" value="missing.vol"/></volume>
  </medium>
</scene>
"""
    proc, out = convert(tmp_path, *GRAINS, scene=scene)
    assert proc.returncode == 0, proc.stderr
    m = medium(out, "interior")
    assert m.get("type") == "discrete" and prop(m, "scale").get("value") == "3"
    assert prop(m, "sigma_t").tag == "volume" and prop(m, "sigma_t").get("type") == "gridvolume"
    assert "the gridvolume is the grains' number density" in proc.stdout
    assert "medium lost (heterogeneous): left unchanged" in proc.stdout and medium(out, "lost").get("type") == "heterogeneous"
    assert prop(m, "to_world") is None and "the sigma_t grid places the grains" in proc.stdout


@pytest.mark.parametrize("case,args,word", [
    ("missing", ["--radius-median", "20"], "cannot read"),
    ("unparsable", ["--radius-median", "20"], "not valid XML"),
    ("unknown medium", ["--medium", "haze", "--radius-median", "20"], "--medium haze"),
    ("no homogeneous", ["--radius-median", "20"], "no homogeneous or heterogeneous medium"),
    ("no grain size", [], "--radius-median is required"),
    ("bad type", ["--radius-median", "twenty"], "<float>"),
])
def test_errors_exit_2_with_one_line(tmp_path, case, args, word):
    scenes = {"missing": None, "unparsable": "<scene version='3.0.0'><shape>",
              "no homogeneous": FLAT.replace("homogeneous", "discrete")}
    proc, out = convert(tmp_path, *args, scene=scenes.get(case, SCENE))
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1 and err[0].startswith("motes: error:") and word in err[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_the_converter_sets_only_the_discrete_mediums_parameters():
    from motes.convert import PARAMETER_TAGS
    from motes.plugins.discrete_medium import PARAMETERS

    assert set(PARAMETER_TAGS) <= set(PARAMETERS)
