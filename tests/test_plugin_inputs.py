"""Malformed `discrete` medium parameters become one clear error or warning naming the parameter (issue 11)."""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

import motes

mi = pytest.importorskip("mitsuba")


def load(**kw):
    motes.set_variant("scalar_rgb")
    d = {"type": "discrete", "count": 200, "phase": {"type": "particle"}}
    d.update(kw)
    return mi.load_dict(d)


@pytest.mark.parametrize("kw,words", [
    ({"material": "ice", "eta": 1.5}, ["material", "eta"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "materail": "ice"}])}, ["materail", "allowed"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "eta": [1.5]}])}, ["eta", "[n, k]"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "eta": 1.5, "share": "lots"}])}, ["share"]),
    ({"species": json.dumps([{"psd": {"type": "monodisperse", "radius_um": 5}, "eta": 1.5, "material": "ice"}])}, ["material", "eta"]),
    ({"to_world": "flat"}, ["to_world", "singular"]),
])
def test_bad_parameters_name_themselves(kw, words):
    motes.set_variant("scalar_rgb")
    if kw.get("to_world") == "flat":
        kw = dict(kw, to_world=mi.ScalarTransform4f().scale([1, 0, 1]))
    with pytest.raises(Exception) as e:
        load(**kw)
    msg = str(e.value)
    assert all(w in msg for w in words), msg


def test_query_radius_as_large_as_the_box_warns():
    with pytest.warns(UserWarning, match="comparable to the particles' extent"):
        load(query_radius=1.5)


def test_relative_filename_resolves_against_the_scene_folder(tmp_path):
    motes.set_variant("scalar_rgb")
    sub = tmp_path / "scene"
    sub.mkdir()
    pos = np.random.default_rng(0).uniform(-1, 1, (100, 3))
    motes.save_particles(sub / "grains.npz", motes.ParticleSet(pos, np.full(100, 30.0), np.zeros(100, dtype=np.int64)))
    (sub / "s.xml").write_text('<scene version="3.0.0"><shape type="cube"><bsdf type="null"/>'
                               '<medium type="discrete" name="interior"><string name="filename" value="grains.npz"/>'
                               '<phase type="particle"/></medium></shape></scene>')
    scene = mi.load_file(str(sub / "s.xml"))
    assert len(scene.shapes()[0].interior_medium().data) == 100
