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
                                  ["equivalent", "--help"]])
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


def test_render_writes_exr_and_png(tmp_path):
    pytest.importorskip("mitsuba")
    out = tmp_path / "dust.exr"
    r = subprocess.run([sys.executable, "-m", "motes", "render", str(ROOT / "scenes_xml" / "dust_box.xml"), "-s", "2",
                        "-D", "res=16", "-D", "count=2000", "--png", "-o", str(out)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert out.is_file() and out.with_suffix(".png").is_file()
    assert "peak memory" in r.stderr


def test_equivalent_xml_loads_in_mitsuba(tmp_path, capsys):
    mi = pytest.importorskip("mitsuba")
    assert main(["equivalent", "--density", "1e9", "--radius-median", "20"]) == 0
    xml = capsys.readouterr().out
    motes.set_variant("scalar_rgb")
    scene = f'<scene version="3.0.0"><shape type="cube"><bsdf type="null"/>{xml}</shape></scene>'
    assert mi.load_string(scene) is not None
