"""A drop-in medium (issue 43): a scene's ``homogeneous`` medium turned ``discrete`` by changing its type and adding a
grain size; without ``to_world`` its grains fill the shapes that hold it, as ``homogeneous`` does (``test_fill.py``).

* ``sigma_t`` (float, rgb, spectrum) times ``scale`` sets the number of grains from their own truncated extinction:
  the core's optical depth over many rays through the box gives the transmittance exp(-sigma_t L);
* ``albedo`` as rgb replaces the grains' albedo per channel;
* the ``<phase>`` child (``isotropic``, ``hg``, ``tabphase``) becomes the grains' phase function; other types fail
  naming themselves;
* ``has_spectral_extinction`` and ``sample_emitters`` are taken; every bad parameter is listed in one error, which
  the ``motes`` command prints in one line;
* three third-party-shaped scenes load, render, and (grey ``sigma_t``) match their ``homogeneous`` originals'
  per-channel means within 5 %, with no ``to_world`` given.
"""

from __future__ import annotations

import contextlib
import io
import warnings

import numpy as np
import pytest

import motes
from _scenes import medium_xml, sensor_xml

mi = pytest.importorskip("mitsuba")

GRAINS = '<float name="radius_median" value="20"/>'

HEAD = """<scene version="3.0.0">
  <integrator type="volpath"><integer name="max_depth" value="64"/></integrator>
""" + sensor_xml(40, "0, 0.5, 8", "{res}", "{spp}", '<integer name="seed" value="1"/>', '<rfilter type="box"/>') + """  <emitter type="constant"><rgb name="radiance" value="0.3"/></emitter>
  <emitter type="directional"><vector name="direction" value="-1, -1, -0.5"/><rgb name="irradiance" value="3"/></emitter>
"""

#: (a) Two meshes (a cube and a sphere, side by side) sharing one medium: sigma_t 1 times scale 3, an rgb albedo,
#: an isotropic phase function.
SHARED = HEAD + medium_xml("homogeneous", [("float", "sigma_t", 1), ("float", "scale", 3), ("rgb", "albedo", "0.9, 0.6, 0.3")],
                 '<phase type="isotropic"/>', 'id="fog"', "  ") + """  <shape type="cube" id="left">
    <transform name="to_world"><translate value="-1, 0, 0"/></transform>
    <bsdf type="null"/><ref name="interior" id="fog"/>
  </shape>
  <shape type="sphere" id="right">
    <point name="center" value="1, 0, 0"/><float name="radius" value="1"/>
    <bsdf type="null"/><ref name="interior" id="fog"/>
  </shape>
</scene>"""

ROTATION = '<transform name="to_world"><rotate value="0.70710678, 0.70710678, 0" angle="30"/></transform>'
#: (b) A rotated shape: Henyey-Greenstein g = 0.7, has_spectral_extinction and sample_emitters given.
ROTATED = HEAD + f"""  <shape type="cube" id="crate">
    {ROTATION}
    <bsdf type="null"/>
""" + medium_xml("homogeneous", [("float", "sigma_t", 2), ("float", "albedo", 0.8),
                            ("boolean", "has_spectral_extinction", "false"), ("boolean", "sample_emitters", "false")],
                 '<phase type="hg"><float name="g" value="0.7"/></phase>') + """  </shape>
</scene>"""

#: (c) A ball with a coloured sigma_t (rgb in [0, 1] times scale, Mitsuba's idiom).
BALL = HEAD + """  <shape type="sphere" id="ball">
    <float name="radius" value="1.6"/>
    <bsdf type="null"/>
""" + medium_xml("homogeneous", [("rgb", "sigma_t", "0.25, 0.5, 1"), ("float", "scale", 2),
                            ("rgb", "albedo", "0.95, 0.9, 0.85")], '<phase type="hg"><float name="g" value="0.3"/></phase>') + """  </shape>
</scene>"""

#: name -> (scene, what its discrete medium adds beside the grain size (no to_world: the grains fill the shapes that
#: hold it); grey sigma_t). The rotated crate takes scale_m = 1 cm (8e5 grains); with the default 1 mm (8e3 grains)
#: it renders 0.4 % brighter than homogeneous (6 % before the grains' continuous equivalent was confined to the
#: crate's inside; scripts/bench/bench_dropin.py --rotated-study).
SCENES = {
    "shared": (SHARED, "", True),
    "rotated": (ROTATED, '<float name="scale_m" value="0.01"/>', True),
    "ball": (BALL, "", False),
}


def dropin(xml: str, box: str, grains: str = GRAINS) -> str:
    """The user's edit: type homogeneous -> discrete, a grain size (and ``box``: what else the scene adds) beside the
    phase child."""
    assert xml.count('type="homogeneous"') == 1
    return xml.replace('type="homogeneous"', 'type="discrete"').replace("<phase", f"{grains}{box}\n    <phase", 1)


def load(xml: str, **fmt):
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        scene = mi.load_string(xml.format(**{"spp": 64, "res": 32, **fmt}))
    return scene, [str(w.message) for w in record]


def medium_of(scene):
    return scene.shapes()[0].interior_medium()


# -- sigma_t and scale ---------------------------------------------------------------------------------------------
def _transmittance_depth(data, to_world: np.ndarray, n: int = 200_000, seed: int = 0) -> float:
    """-ln of the mean transmittance exp(-tau) of the core's optical depth over ``n`` rays along the box's local z,
    spread uniformly over its local cross-section [-1, 1]^2 (every grain's disk met by its share of the rays)."""
    rng = np.random.default_rng(seed)
    local = np.column_stack([rng.uniform(-1, 1, (n, 2)), np.full(n, -3.0)])
    o = local @ to_world[:3, :3].T + to_world[:3, 3]
    d = to_world[:3, :3] @ np.array([0.0, 0.0, 1.0])
    length = float(np.linalg.norm(d))
    tau = data.optical_depth(o, d / length, 0.0, 6.0 * length)
    t = np.exp(-tau)
    return float(-np.log(t.mean()))


@pytest.mark.parametrize("storage,radius_sigma_g,sigma_t", [
    ("compact", 1.5, {"sigma_t": 0.5, "scale": 1.5}),
    ("procedural", 1.5, {"sigma_t": 0.75}),
    ("full", 1.0, {"sigma_t": {"type": "rgb", "value": [0.75, 0.75, 0.75]}}),
])
def test_sigma_t_gives_the_transmittance_of_homogeneous(storage, radius_sigma_g, sigma_t):
    """The grains' number solved from their own truncated C_ext: the mean transmittance along rays through a rotated,
    stretched box is exp(-sigma_t L) (L = 2 scene units along its local z, scaled by 1.5), |rel. error| < 3 %."""
    motes.set_variant("scalar_rgb")
    to_world = (mi.ScalarTransform4f().translate([0.5, -0.2, 0.1]) @ mi.ScalarTransform4f().rotate([0.6, 0.0, 0.8], 40)
                @ mi.ScalarTransform4f().scale([1.2, 0.8, 1.5]))
    medium = mi.load_dict({"type": "discrete", "radius_median": 20.0, "radius_sigma_g": radius_sigma_g, "scale_m": 1e-2,
                           "storage": storage, "to_world": to_world, **sigma_t})
    m = np.array(to_world.matrix, dtype=np.float64)
    expect = 0.75 * 2.0 * 1.5  # sigma_t per scene unit times the box's depth along its local z
    depth = _transmittance_depth(medium.data, m)
    assert abs(depth / expect - 1) < 0.03, (depth, expect, len(medium.data))


def test_count_is_sigma_t_over_the_grains_own_extinction():
    """The count is sigma_t V / <C_ext> with the medium's own grey C_ext (each bin's truncated Q_ext times pi r^2):
    a full-storage medium's grains sum to sigma_t times the box's volume, within their sampling noise."""
    motes.set_variant("scalar_rgb")
    medium = mi.load_dict({"type": "discrete", "sigma_t": 2.0, "radius_median": 20.0, "scale_m": 1e-2, "storage": "full",
                           "to_world": mi.ScalarTransform4f().scale([2.0, 1.0, 0.5])})
    d = medium.data
    volume = 8.0 * 2.0 * 1.0 * 0.5
    total = float(d.c_ext_scene.sum())  # scene units^2
    n = len(d)
    rel_se = float(np.std(d.c_ext_scene) / np.mean(d.c_ext_scene)) / np.sqrt(n)
    assert abs(total / (2.0 * volume) - 1) < 4 * rel_se + 2e-3, (total, 2.0 * volume, n)
    # The untruncated (textbook) cross section would give far fewer grains for the same sigma_t.
    from motes.discrete import mean_extinction_um2

    grains = [motes.Species(motes.LogNormal(20.0, 1.5), 1.31)]
    c_t = mean_extinction_um2(grains, d.wavelength_um, truncate_below_rad=None)
    c = mean_extinction_um2(grains, d.wavelength_um)
    assert c_t > 1.3 * c


def test_scale_alone_is_sigma_t_one_times_scale():
    motes.set_variant("scalar_rgb")
    a = mi.load_dict({"type": "discrete", "scale": 3.0, "radius_median": 20.0})
    b = mi.load_dict({"type": "discrete", "sigma_t": 3.0, "radius_median": 20.0})
    c = mi.load_dict({"type": "discrete", "sigma_t": 1.0, "scale": 3.0, "radius_median": 20.0})
    assert len(a.data) == len(b.data) == len(c.data) > 1000


def test_coloured_sigma_t_uses_its_mean_and_says_so_once():
    motes.set_variant("scalar_rgb")
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        coloured = mi.load_dict({"type": "discrete", "sigma_t": {"type": "rgb", "value": [0.25, 0.5, 1.0]},
                                 "scale": 2.0, "radius_median": 20.0})
    said = [str(w.message) for w in record if "sigma_t" in str(w.message)]
    assert len(said) == 1 and "coloured" in said[0] and "mean" in said[0] and "\n" not in said[0], said
    grey = mi.load_dict({"type": "discrete", "sigma_t": 2.0 * (0.25 + 0.5 + 1.0) / 3, "radius_median": 20.0})
    assert len(coloured.data) == len(grey.data)


def test_sigma_t_in_a_spectral_variant():
    """A spectrum sigma_t (as Mitsuba hands it) and an rgb albedo in scalar_spectral: evaluated at the medium's
    wavelengths; a flat spectrum gives the grey count."""
    motes.set_variant("scalar_spectral")
    try:
        a = mi.load_dict({"type": "discrete", "sigma_t": {"type": "spectrum", "value": 1.5}, "radius_median": 20.0,
                          "albedo": {"type": "rgb", "value": [0.9, 0.5, 0.2]}, "size_bins": 4})
        b = mi.load_dict({"type": "discrete", "sigma_t": 1.5, "radius_median": 20.0, "size_bins": 4})
        assert len(a.data) == len(b.data)
    finally:
        motes.set_variant("scalar_rgb")


# -- albedo ----------------------------------------------------------------------------------------------------------
def test_rgb_albedo_replaces_the_grains_albedo_per_channel():
    """sigma_s per channel at the grains (Eq. 24, grey extinction) is in the ratio of the rgb albedo's channels."""
    motes.set_variant("scalar_rgb")
    medium = mi.load_dict({"type": "discrete", "count": 2000, "radius_median": 20.0, "storage": "full",
                           "albedo": {"type": "rgb", "value": [0.9, 0.6, 0.3]}})
    d = medium.data
    s, _ = d.local_scattering(d.positions[:200], 1.0)
    hit = s[:, 0] > 0
    assert hit.all()
    np.testing.assert_allclose(s[hit] / s[hit, :1], np.broadcast_to([1.0, 2 / 3, 1 / 3], s[hit].shape), rtol=1e-6)


def test_albedo_per_channel_in_the_python_api():
    """DiscreteMedium(albedo=[...]) in the order of the wavelengths as given; one number as before."""
    from motes.discrete import _BinTables
    from motes.ensemble import Species
    from motes.psd import LogNormal

    lam_in = np.array([0.630, 0.532, 0.467])
    lam = np.sort(lam_in)
    rank = np.searchsorted(lam, lam_in)
    sp = Species(LogNormal(30.0, 1.3), 1.31)
    t = _BinTables(lam, rank, 1.0, "auto", 0.03, [0.9, 0.6, 0.3])
    t.add(0, sp, 25.0, 35.0)
    np.testing.assert_array_equal(t.albedos[0][rank], [0.9, 0.6, 0.3])
    one = _BinTables(lam, rank, 1.0, "auto", 0.03, 0.5)
    one.add(0, sp, 25.0, 35.0)
    np.testing.assert_array_equal(one.albedos[0], np.full(3, 0.5))
    for bad in ([0.9, 0.6], [0.9, 0.6, 1.2]):
        with pytest.raises(ValueError, match="albedo"):
            _BinTables(lam, rank, 1.0, "auto", 0.03, bad)


# -- the phase child -------------------------------------------------------------------------------------------------
def _g_of_tabphase(values) -> float:
    """g of Mitsuba's tabphase: piecewise linear on a regular mu grid from -1 to 1, normalised (exact integrals)."""
    v = np.asarray(values, dtype=np.float64)
    mu = np.linspace(-1, 1, v.size)
    a, b, fa, fb = mu[:-1], mu[1:], v[:-1], v[1:]
    norm = np.sum((fa + fb) / 2 * (b - a))
    # int mu f dmu over each segment of a linear f: (b - a) (a (2 fa + fb) + b (fa + 2 fb)) / 6
    return float(np.sum((b - a) * (a * (2 * fa + fb) + b * (fa + 2 * fb)) / 6) / norm)


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
@pytest.mark.parametrize("phase,g", [
    ({"type": "hg", "g": 0.7}, 0.7),
    ({"type": "isotropic"}, 0.0),
    ({"type": "tabphase", "values": "0.2, 0.5, 1.0, 3.0"}, _g_of_tabphase([0.2, 0.5, 1.0, 3.0])),
])
def test_phase_child_becomes_the_grains_phase_function(variant, phase, g):
    """Every bin's and channel's table has the child's mean cosine; phase samples at the grains (the render's tables)
    have it too; the medium's phase function is still ``particle``."""
    motes.set_variant(variant)
    medium = mi.load_dict({"type": "discrete", "sigma_t": 1.0, "radius_median": 20.0, "storage": "full", "phase": phase})
    d = medium.data
    np.testing.assert_allclose(np.asarray(d.bin_g), g, atol=2e-3)
    assert "ParticlePhase" in str(medium.phase_function())
    rng = np.random.default_rng(1)
    n = 20000
    pts = d.positions[rng.integers(0, len(d), n)]
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    wo, _, pdf = d.sample_local(pts, dirs, rng.random(n), rng.random((n, 2)))
    assert np.all(pdf > 0)
    cos = np.sum(wo * dirs, axis=1)
    assert abs(cos.mean() - g) < 4 * cos.std() / np.sqrt(n) + 2e-3


def test_no_phase_child_is_particle_the_grains_own():
    motes.set_variant("scalar_rgb")
    none = mi.load_dict({"type": "discrete", "count": 500, "radius_median": 20.0})
    particle = mi.load_dict({"type": "discrete", "count": 500, "radius_median": 20.0, "phase": {"type": "particle"}})
    np.testing.assert_array_equal(np.asarray(none.data.bin_g), np.asarray(particle.data.bin_g))
    assert 0.7 < float(np.min(particle.data.bin_g)) < 1.0


def test_other_phase_types_name_themselves_and_the_allowed_ones():
    motes.set_variant("scalar_rgb")
    with pytest.raises(RuntimeError) as e:
        mi.load_dict({"type": "discrete", "count": 500, "phase": {"type": "rayleigh"}})
    msg = str(e.value)
    assert all(w in msg for w in ('<phase type="rayleigh">', "particle", "isotropic", "hg", "tabphase")), msg
    assert "Traceback" not in msg
    with pytest.raises(RuntimeError, match="phase_model"):
        mi.load_dict({"type": "discrete", "count": 500, "phase_model": "hg", "phase": {"type": "hg", "g": 0.5}})


# -- homogeneous-only keys, and one error for all bad parameters ------------------------------------------------------
def test_has_spectral_extinction_warns_once_where_it_asks_for_spectral_flights():
    motes.set_variant("scalar_rgb")
    for value, expected in ((True, 1), (False, 0)):
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            mi.load_dict({"type": "discrete", "count": 500, "has_spectral_extinction": value})
        said = [str(w.message) for w in record if "has_spectral_extinction" in str(w.message)]
        assert len(said) == expected, said


def test_sample_emitters_is_taken():
    motes.set_variant("llvm_ad_rgb")
    assert not mi.load_dict({"type": "discrete", "count": 500, "sample_emitters": False}).use_emitter_sampling()
    assert mi.load_dict({"type": "discrete", "count": 500}).use_emitter_sampling()


BAD = """<scene version="3.0.0">
  <shape type="cube"><bsdf type="null"/>
    <medium type="discrete" name="interior">
      <float name="sigma_t" value="1"/>
      <integer name="count" value="500"/>
      <rgb name="albedo" value="0.9, 0.5, 1.5"/>
      <float name="radius_median" value="-20"/>
      <string name="method" value="magic"/>
      <float name="radius_medain" value="20"/>
      <phase type="hg"><float name="g" value="0.5"/></phase>
      <string name="phase_model" value="hg"/>
    </medium>
  </shape>
</scene>"""
#: Each bad parameter of BAD and the words its entry must hold.
BAD_WORDS = [["count", "sigma_t"], ["albedo", "[0, 1]"], ["radius_median", "-20"], ["method", "magic", "mie"],
             ["radius_medain", "did you mean radius_median"], ["phase_model", 'phase type="hg"']]


def test_every_bad_parameter_in_one_error_without_a_traceback():
    motes.set_variant("scalar_rgb")
    with pytest.raises(RuntimeError) as e:
        mi.load_string(BAD)
    msg = str(e.value)
    assert "Traceback" not in msg and 'File "' not in msg, msg
    assert f"{len(BAD_WORDS)} problems" in msg, msg
    entries = msg.split("problems with its parameters:")[1].split(";\n")
    assert len(entries) == len(BAD_WORDS), entries
    for words in BAD_WORDS:
        assert any(all(w in entry for w in words) for entry in entries), (words, entries)


def test_the_command_prints_it_in_one_line(tmp_path):
    from motes import cli

    path = tmp_path / "scene.xml"
    path.write_text(BAD.replace("<scene version=\"3.0.0\">", """<scene version="3.0.0">
  <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="4"/>
    <integer name="height" value="4"/></film></sensor>"""))
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = cli.main(["render", str(path), "-m", "scalar_rgb", "-s", "1", "-o", str(tmp_path / "out.exr")])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip() and not ln.startswith(("motes: load", "  ["))]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("motes: error: "), lines
    assert "Traceback" not in lines[0]
    for words in BAD_WORDS:
        assert all(w in lines[0] for w in words), (words, lines[0])


def test_one_bad_parameter_reads_as_before():
    motes.set_variant("scalar_rgb")
    with pytest.raises(RuntimeError) as e:
        mi.load_dict({"type": "discrete", "count": 0})
    msg = str(e.value)
    assert "ValueError: discrete medium: invalid count = 0: must be an integer in [1, 1e9]" in msg, msg
    assert "problems" not in msg and "Traceback" not in msg


# -- three third-party-shaped scenes --------------------------------------------------------------------------------
def _medium_means(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return img.reshape(-1, img.shape[-1])[mask.ravel(), :3].mean(axis=0)


@pytest.mark.parametrize("name", list(SCENES))
def test_a_homogeneous_scene_turned_discrete_renders_like_it(name):
    """Load, render at 32 px / 64 spp (fixed seeds), finite; with a grey sigma_t each channel's mean over the pixels
    that see the medium within 5 % of the homogeneous render's (the coloured one: one warning saying so)."""
    motes.set_variant("scalar_rgb")
    xml, box, grey = SCENES[name]
    homogeneous, said_h = load(xml)
    discrete, said_d = load(dropin(xml, box))
    assert said_h == [] and len(said_d) == (0 if grey else 1), said_d
    assert isinstance(medium_of(discrete).data, motes.DiscreteMedium)
    a = np.array(mi.render(homogeneous, spp=64))
    b = np.array(mi.render(discrete, spp=64))
    assert np.all(np.isfinite(b)) and b.shape == a.shape == (32, 32, a.shape[-1])
    # The pixels that see the medium: a clear view shows the sky's 0.3 exactly.
    mask = np.any(np.abs(a[..., :3] - 0.3) > 1e-3, axis=-1)
    assert mask.sum() > 200
    ma, mb = _medium_means(a, mask), _medium_means(b, mask)
    if grey:
        assert np.all(np.abs(mb / ma - 1) < 0.05), (ma, mb)
    else:
        assert "coloured" in said_d[0]


def test_the_comparison_sees_a_wrong_density():
    """The 5 % criterion is sharp enough: half the grains fail it."""
    motes.set_variant("scalar_rgb")
    xml, box, _ = SCENES["shared"]
    a = np.array(mi.render(load(xml)[0], spp=64))
    b = np.array(mi.render(load(dropin(xml.replace('name="scale" value="3"', 'name="scale" value="1.5"'), box))[0], spp=64))
    mask = np.any(np.abs(a[..., :3] - 0.3) > 1e-3, axis=-1)
    assert np.any(np.abs(_medium_means(b, mask) / _medium_means(a, mask) - 1) > 0.05)


def test_the_parameter_table_lists_every_parameter():
    """The docstring table (the one users read) and the names the plugin knows agree."""
    import re

    from motes.plugins import discrete_medium

    table = discrete_medium.__doc__.split("===========================  =========")[2]
    rows = {n for pair in re.findall(r"^``(\w+)``(?:, ``(\w+)``)?", table, flags=re.M) for n in pair if n}
    known = set(discrete_medium.PARAMETERS)
    assert rows <= known, rows - known
    assert all(f"``{name}``" in table for name in known), [n for n in known if f"``{n}``" not in table]


def test_only_a_users_error_loses_its_traceback():
    """motes._errors: the frames go where the plugin rejected an input (ValueError, MemoryError) and stay where it
    failed (a bug keeps its traceback)."""
    from motes._errors import without_traceback

    frames = '  File "/x/plugins/__init__.py", line 84, in <lambda>\n  File "/x/discrete_medium.py", line 9, in make\n'
    head = '[parser.cpp:1718] At a.xml (line 3, col 2): failed to instantiate medium plugin of type "discrete": '
    text = head + "Traceback (most recent call last):\n" + frames + "ValueError: discrete medium: 2 problems:\n  a;\n  b"
    assert without_traceback(text) == head.rstrip() + " ValueError: discrete medium: 2 problems:\n  a;\n  b"
    assert without_traceback(head + "Traceback (most recent call last):\n" + frames + "AttributeError: x") is None
    assert without_traceback("no traceback here") is None


# -- From a heterogeneous medium: a sigma_t volume ------------------------------------------------------------

def _smoke_vol(path, half_empty: bool = False) -> str:
    """A 8 x 5 x 6 grid of a Gaussian puff (x fastest), written as a Mitsuba .vol file; ``half_empty``: zero where
    x < 1/2 of the grid."""
    import mitsuba as mi

    z, y, x = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 5), np.linspace(0, 1, 8), indexing="ij")
    a = np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2) / 0.05) * 4.0
    if half_empty:
        a[:, :, :4] = 0.0
    mi.VolumeGrid(a.astype(np.float32)[..., None]).write(str(path))
    return str(path)


def _heterogeneous(kind: str, vol: str, grid_to_world=None, **extra):
    import mitsuba as mi

    T = mi.ScalarTransform4f
    volume = {"type": "gridvolume", "filename": vol, "to_world": grid_to_world or T().translate([-1, -1, -1]).scale(2)}
    med = {"type": kind, "sigma_t": volume, "scale": 30.0, "albedo": 0.9, "phase": {"type": "isotropic"}}
    if kind == "discrete":
        med.update(radius_median=20.0, scale_m=1e-3, **extra)
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1_000_000},
        "sensor": {"type": "perspective", "fov": 40, "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 64}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.1}},
        "sun": {"type": "directional", "direction": [0.5, -0.6, -0.4], "irradiance": {"type": "rgb", "value": 5.0}},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": med}})


def test_a_sigma_t_volume_places_the_grains_by_its_density(tmp_path):
    """A gridvolume sigma_t (heterogeneous's): the count is the grid's mean times its box over <C_ext>, the grains
    lie where the grid is not zero, in its box (its to_world), and a heterogeneous scene turned discrete renders
    like it (isotropic phase on both; 16 px, 4 x 64 spp)."""
    motes.set_variant("scalar_rgb")
    import mitsuba as mi
    from motes.plugins.cameras import discrete_media

    vol = _smoke_vol(tmp_path / "half.vol", half_empty=True)
    (data,) = discrete_media(_heterogeneous("discrete", vol, storage="full"))
    pos = np.asarray(data.positions)
    assert np.all(np.abs(pos) <= 1 + 1e-9)
    # The grid is zero for x < 1/2 of it (cells 0-3 of 8): interpolated, nothing left of the 4th cell centre.
    assert pos[:, 0].min() > -1 + 2 * 3.5 / 8 - 1e-9
    full = _smoke_vol(tmp_path / "puff.vol")
    het, dis = _heterogeneous("heterogeneous", full), _heterogeneous("discrete", full)
    means = [np.mean([float(np.asarray(mi.render(sc, spp=64, seed=s)).mean()) for s in range(4)]) for sc in (het, dis)]
    assert means[1] == pytest.approx(means[0], rel=0.05), means


def test_a_sigma_t_volume_refuses_what_it_cannot_place(tmp_path):
    """A rotated grid, and a to_world or distribution beside the volume, fail with one line naming them."""
    motes.set_variant("scalar_rgb")
    import mitsuba as mi

    vol = _smoke_vol(tmp_path / "puff.vol")
    T = mi.ScalarTransform4f
    with pytest.raises(RuntimeError, match="rotates or shears"):
        _heterogeneous("discrete", vol, grid_to_world=T().rotate([0, 0, 1], 30).translate([-1, -1, -1]).scale(2))
    with pytest.raises(RuntimeError, match="remove the medium's to_world"):
        _heterogeneous("discrete", vol, to_world=T().scale(2))
    with pytest.raises(RuntimeError, match="remove the medium's distribution"):
        _heterogeneous("discrete", vol, distribution="noise")
