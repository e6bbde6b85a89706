"""A ``discrete`` medium outside the shape that holds it warns at load (issue 23.3).

The trap: a medium's ``to_world`` that does not map its local cube onto the shape (here the identity, given
explicitly; or a particle file in other units) puts the particles outside the shape, and the render shows an
empty medium. A medium without ``to_world`` or file fills the shapes that hold it (issue 43) and never warns. Loading must say so, naming ``to_world``
and giving both boxes, through ``mi.load_dict``, ``mi.load_file``, ``mi.load_string`` and ``motes render``,
on both render paths (native, and the evaluated-mode Python path with ``MOTES_NATIVE=0``); and stay quiet on
scenes that are right.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import motes
from _scenes import discrete_xml
from conftest import hsettings
from motes.plugins.scene_checks import INSIDE_WARN_SHARE, inside_share

mi = pytest.importorskip("mitsuba")
ROOT = pathlib.Path(__file__).resolve().parent.parent

SHIFT = "<scale value=\"0.1\"/><translate x=\"3\" y=\"0\" z=\"0\"/>"


#: The medium's to_world of the trap: the identity, given (without any the medium fills the cube).
IDENTITY = '<transform name="to_world"><translate value="0, 0, 0"/></transform>'


def xml(medium_to_world: bool | None) -> str:
    """A 0.2-wide cube moved to x = 3; the medium's generated particles fill its local cube [-1, 1]^3 through its
    to_world, so they land inside only when the medium repeats the cube's to_world (True; False: the identity;
    None: no to_world, the grains fill the cube)."""
    mt = {True: f'<transform name="to_world">{SHIFT}</transform>', False: IDENTITY, None: ""}[medium_to_world]
    return f"""<scene version="3.0.0">
  <integrator type="volpath"/>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="3, 0, 5" target="3, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    <sampler type="independent"><integer name="sample_count" value="2"/></sampler>
  </sensor>
  <emitter type="constant"/>
  <shape type="cube" id="box">
    <transform name="to_world">{SHIFT}</transform>
    <bsdf type="null"/>
    {discrete_xml(500, 50, mt, ident="dust")}
  </shape>
</scene>"""


def scene_dict(medium_to_world: bool | None) -> dict:
    t = mi.ScalarTransform4f().translate([3, 0, 0]) @ mi.ScalarTransform4f().scale(0.1)
    medium = {"type": "discrete", "id": "dust", "count": 500, "radius_median": 50.0, "scale_m": 0.01,
              "phase": {"type": "particle"}}
    if medium_to_world is not None:
        medium["to_world"] = t if medium_to_world else mi.ScalarTransform4f()
    return {"type": "scene", "integrator": {"type": "volpath"},
            "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}},
            "env": {"type": "constant"},
            "box": {"type": "cube", "to_world": t, "bsdf": {"type": "null"}, "interior": medium}}


def outside_messages(record) -> list[str]:
    return [str(w.message) for w in record if "lies mostly outside" in str(w.message)]


@given(st.lists(st.floats(-10, 10), min_size=12, max_size=12))
@hsettings(200)
def test_inside_share_is_a_share(v):
    lo, hi = np.minimum(v[0:3], v[3:6]), np.maximum(v[0:3], v[3:6])
    s_lo, s_hi = np.minimum(v[6:9], v[9:12]), np.maximum(v[6:9], v[9:12])
    share = inside_share(lo, hi, s_lo, s_hi)
    assert 0.0 <= share <= 1.0
    assert inside_share(lo, hi, lo, hi) == 1.0  # a box lies in itself, flat axes included
    assert inside_share(lo, hi, np.minimum(lo, s_lo), np.maximum(hi, s_hi)) == 1.0


def test_inside_share_values():
    assert inside_share([0, 0, 0], [2, 1, 1], [1, -5, -5], [5, 5, 5]) == pytest.approx(0.5)
    assert inside_share([0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]) == 0.0
    assert inside_share([0, 0, 0], [1, 1, 0], [0, 0, -1], [1, 1, 1]) == 1.0  # flat along z, inside
    assert inside_share([0, 0, 2], [1, 1, 2], [0, 0, -1], [1, 1, 1]) == 0.0  # flat along z, outside


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_load_dict_warns_with_to_world_and_both_boxes(variant):
    motes.set_variant(variant)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        mi.load_dict(scene_dict(medium_to_world=False))
    (msg,) = outside_messages(record)
    assert "to_world" in msg and "'dust'" in msg and "'box'" in msg and "0% of the particles' box inside" in msg
    # both boxes, in scene units: particles in about [-1, 1]^3, the shape in [2.9, 3.1] x [-0.1, 0.1]^2
    assert "shape's box (2.9, -0.1, -0.1)..(3.1, 0.1, 0.1)" in msg
    assert "particles' box (-" in msg
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        mi.load_dict(scene_dict(medium_to_world=True))
    assert outside_messages(record) == []
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        scene = mi.load_dict(scene_dict(medium_to_world=None))
    assert outside_messages(record) == []
    lo, hi = scene.shapes()[0].interior_medium().data.centre_box  # filled: inside the cube
    assert np.all(np.asarray(lo) >= [2.9, -0.1, -0.1]) and np.all(np.asarray(hi) <= [3.1, 0.1, 0.1])


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_load_file_and_load_string_warn(tmp_path, variant):
    motes.set_variant(variant)
    path = tmp_path / "shifted.xml"
    path.write_text(xml(medium_to_world=False))
    for load in (lambda: mi.load_file(str(path)), lambda: mi.load_string(xml(medium_to_world=False))):
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            load()
        assert len(outside_messages(record)) == 1
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        mi.load_string(xml(medium_to_world=True))
        mi.load_string(xml(medium_to_world=None))
    assert outside_messages(record) == []


def test_shipped_scenes_load_without_the_warning():
    motes.set_variant("scalar_rgb")
    for path in sorted((ROOT / "scenes_xml").glob("*.xml")) + sorted((ROOT / "mitsuba_plugin/motes/scenes").glob("*.xml")):
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            mi.load_file(str(path), spp=1, res=8)
        assert outside_messages(record) == [], path


@pytest.mark.parametrize("native", ["1", "0"])
def test_both_render_paths_warn_in_a_fresh_process(tmp_path, native):
    """MOTES_NATIVE=0 puts llvm_ad_rgb on the evaluated-mode Python path; 1 on the native one."""
    path = tmp_path / "shifted.xml"
    path.write_text(xml(medium_to_world=False))
    code = textwrap.dedent(f"""
        import warnings, motes, mitsuba as mi
        motes.set_variant("llvm_ad_rgb")
        print("native", "llvm_ad_rgb" in motes.native_variants())
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            mi.load_file({str(path)!r})
        print("warnings", sum("lies mostly outside" in str(w.message) for w in record))
        """)
    env = dict(os.environ, MOTES_NATIVE=native)
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"native {native == '1'}" in r.stdout
    assert "warnings 1" in r.stdout


def test_motes_render_warns_in_one_line(tmp_path):
    path = tmp_path / "shifted.xml"
    path.write_text(xml(medium_to_world=False))
    r = subprocess.run([sys.executable, "-m", "motes", "render", str(path), "-o", str(tmp_path / "out.exr")],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = [ln for ln in r.stderr.splitlines() if "lies mostly outside" in ln]
    assert len(lines) == 1 and "to_world" in lines[0] and "shape's box" in lines[0]


def test_warn_share_is_half():
    assert INSIDE_WARN_SHARE == 0.5


def test_the_advice_is_a_to_world_that_fills_the_holder():
    """Issue 43: the warning gives the to_world that maps the medium's local cube onto the holder's box, which is
    right for any holder (a mesh's own to_world is not: its vertices are not in [-1, 1]^3); with it, the medium
    loads without the warning. The holder here is a sphere given by center and radius (no to_world at all)."""
    motes.set_variant("scalar_rgb")
    medium = {"type": "discrete", "id": "dust", "count": 500, "radius_median": 50.0, "scale_m": 0.01,
              "phase": {"type": "particle"}, "to_world": mi.ScalarTransform4f()}

    def scene(m):
        return {"type": "scene", "integrator": {"type": "volpath"},
                "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}},
                "ball": {"type": "sphere", "center": [4, 1, 0], "radius": 0.5, "bsdf": {"type": "null"},
                         "interior": m}}

    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        mi.load_dict(scene(medium))
    (msg,) = outside_messages(record)
    advice = '<transform name="to_world"><scale value="0.5, 0.5, 0.5"/><translate value="4, 1, 0"/></transform>'
    assert advice in msg and "a mesh's own to_world does not" in msg, msg
    fixed = dict(medium, to_world=mi.ScalarTransform4f().translate([4, 1, 0]) @ mi.ScalarTransform4f().scale(0.5))
    filled = {k: v for k, v in medium.items() if k != "to_world"}  # issue 43: no to_world, it fills the ball
    for m in (fixed, filled):
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            mi.load_dict(scene(m))
        assert outside_messages(record) == []
