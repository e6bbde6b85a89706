"""The ``motes`` command (issue 11): help of every subcommand, one-line errors, a small render."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import numpy as np
import pytest

import motes
from motes.cli import main

ROOT = pathlib.Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("argv", [["--help"], ["render", "--help"], ["optics", "--help"], ["particles", "--help"],
                                  ["equivalent", "--help"], ["scenes", "--help"],
                                  ["convert", "--help"]])
def test_help(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 0
    assert "usage: motes" in capsys.readouterr().out


def test_python_dash_m_runs():
    out = subprocess.run([sys.executable, "-m", "motes", "optics", "--radius", "1"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "Q_ext" in out.stdout


def test_optics_matches_the_api(capsys):
    assert main(["optics", "--radius", "5", "--eta", "1.5+0.01i"]) == 0
    text = capsys.readouterr().out
    q = float(text.split("Q_ext = ")[1].split()[0])
    cs = motes.cross_sections([5.0], 0.55, 1.5 + 0.01j)
    assert abs(q - float(np.asarray(cs["ext"])[0]) / (np.pi * 25)) < 1e-4 * q


@pytest.mark.parametrize("argv,word", [(["optics", "--radius", "5", "--eta", "glass"], "--eta"),
                                       (["optics", "--radius", "-1"], "radius"),
                                       (["particles", "/nonexistent/p.npz"], "p.npz"),
                                       (["render", "/nonexistent/scene.xml"], "scene.xml")])
def test_errors_are_one_line(argv, word, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("motes: error:") and word in err[0], err


def test_particles_summary(tmp_path, capsys):
    pos = np.random.default_rng(0).uniform(-1, 1, (500, 3))
    path = tmp_path / "p.npz"
    motes.save_particles(path, motes.ParticleSet(pos, np.full(500, 20.0), np.zeros(500, dtype=np.int64)))
    assert main(["particles", str(path)]) == 0
    out = capsys.readouterr().out
    assert "500 particles" in out and "median 20" in out
    assert "grid of a discrete medium (query_radius 0): cells" in out


def test_render_writes_exr_and_png(tmp_path):
    pytest.importorskip("mitsuba")
    out = tmp_path / "dust.exr"
    r = subprocess.run([sys.executable, "-m", "motes", "render", str(ROOT / "scenes_xml" / "dust_box.xml"), "-s", "2",
                        "-D", "res=16", "-D", "count=2000", "--png", "-o", str(out)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert out.is_file() and out.with_suffix(".png").is_file()
    assert "peak memory" in r.stderr
    # The load stages with their times.
    for stage in ("particles: 2000 generated in", "optics tables:", "grid: 2000 particles"):
        assert stage in r.stderr, r.stderr


@pytest.mark.parametrize("variant,extra", [("scalar_rgb", []), ("scalar_spectral_polarized", ["--polarized"])])
def test_equivalent_xml_loads_in_mitsuba(tmp_path, capsys, variant, extra):
    mi = pytest.importorskip("mitsuba")
    assert main(["equivalent", "--density", "1e9", "--radius-median", "20", *extra]) == 0
    xml = capsys.readouterr().out
    assert ("motes_tabphase_polarized" in xml) == bool(extra)
    motes.set_variant(variant)
    scene = f'<scene version="3.0.0"><shape type="cube"><bsdf type="null"/>{xml}</shape></scene>'
    assert mi.load_string(scene) is not None


def test_scenes_lists_and_copies_the_shipped_scenes(tmp_path, capsys):
    """The package ships the example scenes (a link to scenes_xml/ in the source tree, a file in the wheel)."""
    assert main(["scenes"]) == 0
    assert "dust_box" in capsys.readouterr().out
    assert main(["scenes", "-o", str(tmp_path)]) == 0
    assert (tmp_path / "dust_box.xml").read_bytes() == (ROOT / "scenes_xml" / "dust_box.xml").read_bytes()


def test_render_by_the_name_of_a_shipped_scene(tmp_path):
    pytest.importorskip("mitsuba")
    r = subprocess.run([sys.executable, "-m", "motes", "render", "dust_box", "-s", "1", "-D", "res=8", "-D", "count=500",
                        "-o", str(tmp_path / "d.exr")], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "shipped scene" in r.stderr and (tmp_path / "d.exr").is_file()


def test_unknown_scene_names_the_shipped_ones(capsys):
    assert main(["render", "no_such_scene"]) == 2
    err = capsys.readouterr().err
    assert "no_such_scene" in err and "dust_box" in err


def test_tonemap_keeps_a_dim_room_readable_beside_a_bright_patch():
    """Reinhard's operator: the patch (1000x the room) saturates, the room lands near mid grey instead of
    black, order is kept, and NaN/negative input cannot leak into the PNG."""
    from motes.cli import tonemap

    img = np.full((64, 64, 3), 0.01)
    img[:8, :8] = 10.0
    img[60:, 60:] = 0.02
    img[0, 63] = np.nan
    img[1, 63] = -1.0
    out = tonemap(img)
    assert np.all(np.isfinite(out)) and out.min() >= 0 and out.max() <= 1
    assert out[0, 0, 0] > 0.99 and 0.1 < out[32, 32, 0] < 0.5
    assert out[62, 62, 0] > out[32, 32, 0]
    assert out[0, 63, 0] == 0 and out[1, 63, 0] == 0


def test_load_stages_are_logged_by_the_api(caplog):
    """The library says its load stages at INFO on the `motes` logger (a log line in the API)."""
    import logging

    with caplog.at_level(logging.INFO, logger="motes"):
        motes.DiscreteMedium(np.zeros((3, 3)), np.full(3, 5.0), np.zeros(3, dtype=np.int64),
                             [motes.Species(motes.LogNormal(5, 1.2), 1.31)], [0.55])
    text = caplog.text
    assert "optics tables:" in text and "grid: 3 particles" in text
