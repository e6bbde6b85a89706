"""Malformed and extreme inputs (issue 11): each row of ``CASES`` is one input a user can give, with the outcome
class it must get — a one-line error naming the parameter (through the ``motes`` command: exit status 2, no
traceback), an exception from the Python API naming it, or a warning — and words the message must hold.
No row may crash, abort or print a traceback.

    .venv/bin/python tests/test_malformed.py     # prints the table of TESTING.md (runs every case)
"""

from __future__ import annotations

import json
import pathlib
import sys
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pytest

import motes

mi = pytest.importorskip("mitsuba")

from test_plugin_inputs import load as _load  # noqa: E402  (a discrete medium of 200 grains, from a dict)

MONO = {"type": "monodisperse", "radius_um": 5}


def _xml_value(name: str, v) -> str:
    if isinstance(v, bool):
        return f'<boolean name="{name}" value="{str(v).lower()}"/>'
    if isinstance(v, int):
        return f'<integer name="{name}" value="{v}"/>'
    if isinstance(v, float):
        return f'<float name="{name}" value="{v!r}"/>'
    if isinstance(v, str) and v.startswith("<transform"):
        return v
    return f'<string name="{name}" value="{_escape(str(v))}"/>'


def _escape(s: str) -> str:
    return s.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;").replace(">", "&gt;")


def scene_xml(medium: dict, medium_type: str = "discrete", phase: str = "particle") -> str:
    """A minimal scene with a cube holding a medium of the given parameters."""
    params = dict(medium)
    if medium_type == "discrete" and "filename" not in params and "count" not in params:
        params["count"] = 200
    body = "\n".join("            " + _xml_value(k, v) for k, v in params.items())
    return f"""<scene version="3.0.0">
    <integrator type="volpath"/>
    <emitter type="constant"/>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/></film>
    </sensor>
    <shape type="cube">
        <bsdf type="null"/>
        <medium type="{medium_type}" name="interior">
{body}
            <phase type="{phase}"/>
        </medium>
    </shape>
</scene>
"""


@dataclass
class Case:
    """One malformed input. ``kind``: "cli" (a scene through ``motes render``: exit 2, one line),
    "error" (a Python API call raises ``exc``), "warning" (a load or call warns)."""

    name: str
    what: str
    kind: str
    words: list[str]
    medium: dict | None = None
    call: Callable | None = None
    exc: type = Exception
    medium_type: str = "discrete"
    setup: Callable | None = field(default=None, repr=False)


def _ply(path: pathlib.Path, pscale: float) -> str:
    meshio = pytest.importorskip("meshio")
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    meshio.write_points_cells(str(path), pts, [], point_data={"pscale": np.full(3, pscale)})
    return str(path)


SINGULAR = '<transform name="to_world"><scale value="1, 0, 1"/></transform>'
CASES = [
    # The discrete medium's parameters, through `motes render` (an XML scene).
    Case("count_zero", "count = 0", "cli", ["count", "[1, 1e9]"], {"count": 0}),
    Case("count_negative", "count = -5", "cli", ["count"], {"count": -5}),
    # 1.5e8 used to abort in the allocator; since compact storage (issue 24) it builds in ~19 GB, so the
    # largest count the plugin takes is what cannot fit (150 GB by the dense estimate).
    Case("count_huge", "count = 1000000000 (more than any medium fits in memory)", "cli", ["count", "GiB"], {"count": 1_000_000_000}),
    Case("radius_median_zero", "radius_median = 0", "cli", ["radius_median"], {"radius_median": 0.0}),
    Case("radius_median_huge", "radius_median = 50000 (outside the PSD range)", "cli", ["radius_median"], {"radius_median": 50000.0}),
    Case("sigma_g_below_one", "radius_sigma_g = 0.5", "cli", ["radius_sigma_g"], {"radius_sigma_g": 0.5}),
    Case("eta_negative", "eta = -1.5", "cli", ["eta"], {"eta": -1.5}),
    Case("eta_k_negative", "eta_k = -0.1 (a gain medium)", "cli", ["eta_k"], {"eta_k": -0.1}),
    Case("material_unknown", 'material = "unobtainium"', "cli", ["material", "unobtainium"], {"material": "unobtainium"}),
    Case("material_and_eta", "material together with eta (eta used to be ignored)", "cli", ["material", "eta"], {"material": "ice", "eta": 1.5}),
    Case("eta_medium_zero", "eta_medium = 0", "cli", ["eta_medium"], {"eta_medium": 0.0}),
    Case("psd_not_json", "psd = '{not json'", "cli", ["psd"], {"psd": "{not json"}),
    Case("species_not_json", "species = '[{'", "cli", ["species"], {"species": "[{"}),
    Case("species_empty", "species = '[]'", "cli", ["species"], {"species": "[]"}),
    Case("species_key_misspelt", 'a species with "materail" (used to be ignored)', "cli", ["materail", "allowed"],
         {"species": json.dumps([{"psd": MONO, "materail": "ice"}])}),
    Case("species_eta_one_number", 'a species with "eta": [1.5] (used to be an IndexError)', "cli", ["eta", "[n, k]"],
         {"species": json.dumps([{"psd": MONO, "eta": [1.5]}])}),
    Case("species_share_text", 'a species with "share": "lots"', "cli", ["share"],
         {"species": json.dumps([{"psd": MONO, "eta": 1.5, "share": "lots"}])}),
    Case("species_material_and_eta", "a species with both material and eta", "cli", ["material", "eta"],
         {"species": json.dumps([{"psd": MONO, "eta": 1.5, "material": "ice"}])}),
    Case("species_psd_type_unknown", 'a species whose psd has "type": "gaussianish"', "cli", ["gaussianish"],
         {"species": json.dumps([{"psd": {"type": "gaussianish"}, "eta": 1.5}])}),
    Case("to_world_singular", "a singular to_world (scale 1, 0, 1)", "cli", ["to_world", "singular"], {"to_world": SINGULAR}),
    Case("query_radius_negative", "query_radius = -1", "cli", ["query_radius"], {"query_radius": -1.0}),
    Case("tau_max_zero", "tau_max = 0", "cli", ["tau_max"], {"tau_max": 0.0}),
    Case("cells_per_particle_zero", "cells_per_particle = 0", "cli", ["cells_per_particle"], {"cells_per_particle": 0.0}),
    Case("continuous_count_zero", "continuous_count = 0", "cli", ["continuous_count"], {"continuous_count": 0.0}),
    Case("scale_m_zero", "scale_m = 0", "cli", ["scale_m"], {"scale_m": 0.0}),
    Case("footprint_k_negative", "footprint_k = -1", "cli", ["footprint_k"],
         {"footprint_k": -1.0, "fov": 40.0, "film_width": 64, "z_med": 10.0}),
    Case("film_width_zero", "film_width = 0 with footprint_k", "cli", ["film_width", ">= 1"],
         {"footprint_k": 0.5, "fov": 40.0, "film_width": 0, "z_med": 10.0}),
    Case("fov_zero", "fov = 0 with footprint_k", "cli", ["fov", "(0, 180)"],
         {"footprint_k": 0.5, "fov": 0.0, "film_width": 64, "z_med": 10.0}),
    Case("z_med_negative", "z_med = -10 with footprint_k", "cli", ["z_med"],
         {"footprint_k": 0.5, "fov": 40.0, "film_width": 64, "z_med": -10.0}),
    Case("footprint_k_alone", "footprint_k without fov, film_width, z_med", "cli", ["footprint_k needs fov"],
         {"footprint_k": 0.5}),
    Case("truncate_below_above_pi", "truncate_below = 4 (negative asks for the default)", "cli", ["truncate_below"],
         {"truncate_below": 4.0}),
    Case("albedo_above_one", "albedo = 1.5", "cli", ["albedo"], {"albedo": 1.5}),
    Case("size_bins_zero", "size_bins = 0", "cli", ["size_bins"], {"size_bins": 0}),
    Case("method_unknown", 'method = "magic"', "cli", ["method"], {"method": "magic"}),
    Case("wavelengths_not_numbers", 'wavelengths = "0.4,abc"', "cli", ["wavelengths"], {"wavelengths": "0.4,abc"}),
    Case("distribution_unknown", 'distribution = "spiral"', "cli", ["distribution"], {"distribution": "spiral"}),
    Case("seed_negative", "seed = -1", "cli", ["seed"], {"seed": -1}),
    Case("parameter_misspelt", "radius_medain = 5 (a misspelt parameter)", "cli", ["radius_medain"], {"radius_medain": 5.0}),
    Case("filename_missing", "filename of a file that does not exist", "cli", ["no such file"], {"filename": "/nonexistent/grains.npz"}),
    Case("filename_unknown_format", "filename of a .txt file", "cli", ["grains.txt"], {"filename": "grains.txt"},
         setup=lambda d: (d / "grains.txt").write_text("1 2 3\n")),
    Case("pscale_implausible", "a PLY whose pscale reads as 3 m grains", "cli", ["huge.ply", "implausible"],
         {"filename": "huge.ply", "scale_m": 1.0}, setup=lambda d: _ply(d / "huge.ply", 3.0)),
    Case("phase_in_other_medium", "the particle phase inside a homogeneous medium", "cli", ['medium type="discrete"'],
         {"sigma_t": 1.0}, medium_type="homogeneous"),
    # Warnings.
    Case("query_radius_as_large_as_box", "query_radius = 1.5 on particles filling [-1, 1]^3", "warning",
         ["comparable to the particles' extent"],
         call=lambda: _load(query_radius=1.5, to_world=__import__("mitsuba").ScalarTransform4f())),
    Case("prbvolpath", "rendering a discrete medium with prbvolpath", "warning", ["prbvolpath", "volpath"],
         call=lambda: _render_with("prbvolpath")),
    # The Python API.
    Case("lognormal_median_negative", "LogNormal(-1, 1.5)", "error", ["median_um"], call=lambda: motes.LogNormal(-1.0, 1.5), exc=ValueError),
    Case("lognormal_sigma_below_one", "LogNormal(10, 0.9)", "error", ["sigma_g", ">= 1"], call=lambda: motes.LogNormal(10.0, 0.9), exc=ValueError),
    Case("psd_sample_huge", "LogNormal(...).sample(10**10) (used to abort)", "error", ["sample(n=10000000000)", "GiB"],
         call=lambda: motes.LogNormal(10.0, 1.5).sample(10**10), exc=MemoryError),
    Case("goa_p_max_huge", "goa_amplitudes(..., p_max=1000) (used to abort)", "error", ["p_max", "[0, 500]"],
         call=lambda: motes.goa_amplitudes(10.0, 0.5, 1.33, np.array([0.1]), p_max=1000), exc=ValueError),
    Case("radius_nan", "cross_sections(nan, ...)", "error", ["radius_um", "NaN"], call=lambda: motes.cross_sections(float("nan"), 0.5, 1.33), exc=ValueError),
    Case("wavelength_zero", "cross_sections(1, 0, ...)", "error", ["wavelength_um"], call=lambda: motes.cross_sections(1.0, 0.0, 1.33), exc=ValueError),
    Case("method_unknown_api", 'cross_sections(..., method="magic")', "error", ["method", "magic"],
         call=lambda: motes.cross_sections(1.0, 0.5, 1.33, method="magic"), exc=ValueError),
    Case("grid_positions_2d", "ParticleGrid with positions of shape (4, 2)", "error", ["positions", "(n, 3)"],
         call=lambda: motes.ParticleGrid(np.zeros((4, 2)), np.ones(4), np.ones(4)), exc=ValueError),
    Case("grid_empty", "ParticleGrid with no particles", "error", ["empty"],
         call=lambda: motes.ParticleGrid(np.zeros((0, 3)), np.ones(0), np.ones(0)), exc=ValueError),
    Case("grid_radii_length", "ParticleGrid with 3 radii for 4 particles", "error", ["radii_um", "one entry per particle"],
         call=lambda: motes.ParticleGrid(np.zeros((4, 3)), np.ones(3), np.ones(4)), exc=ValueError),
    Case("grid_positions_nan", "ParticleGrid with NaN positions", "error", ["positions", "finite"],
         call=lambda: motes.ParticleGrid(np.full((4, 3), np.nan), np.ones(4), np.ones(4)), exc=ValueError),
    Case("grid_query_radius_negative", "ParticleGrid(query_radius=-1)", "error", ["query_radius"],
         call=lambda: motes.ParticleGrid(np.zeros((4, 3)), np.ones(4), np.ones(4), query_radius=-1.0), exc=ValueError),
    Case("load_particles_missing", "load_particles of a missing file", "error", ["nonexistent.npz", "no such file"],
         call=lambda: motes.load_particles("/nonexistent.npz"), exc=ValueError),
]


def _render_with(integrator: str):
    xml = scene_xml({}).replace('<integrator type="volpath"/>', f'<integrator type="{integrator}"/>')
    motes.set_variant("llvm_ad_rgb")
    try:
        mi.render(mi.load_string(xml), spp=1)
    finally:
        motes.set_variant("scalar_rgb")


def run_case(case: Case, tmp: pathlib.Path) -> tuple[str, str, type | None]:
    """(outcome class, message, exception type) of one case: "exit 2" (the command), an exception's type, a
    warning's type, or "no error"."""
    from motes import cli

    motes.set_variant("scalar_rgb")
    if case.setup:
        case.setup(tmp)
    if case.kind == "cli":
        path = tmp / "scene.xml"  # a neutral name: the words must come from the message
        path.write_text(scene_xml(case.medium, case.medium_type))
        import contextlib
        import io

        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            rc = cli.main(["render", str(path), "-m", "scalar_rgb", "-s", "1", "-o", str(tmp / "out.exr")])
        # What the command printed, less its progress lines.
        lines = [ln for ln in err.getvalue().splitlines() if ln.strip() and not ln.startswith(("motes: load", "  ["))]
        return (f"exit {rc}", "\n".join(lines), None)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        try:
            case.call()
        except Exception as e:  # noqa: BLE001 - the outcome is what we report
            return (type(e).__name__, str(e), type(e))
    caught = [x for x in w if issubclass(x.category, (UserWarning, RuntimeWarning))]
    if caught:
        return (caught[0].category.__name__, str(caught[0].message), None)
    return ("no error", "", None)


def test_at_least_forty_cases():
    assert len(CASES) >= 40 and len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_malformed_input(case: Case, tmp_path):
    outcome, msg, raised = run_case(case, tmp_path)
    if case.kind == "cli":
        assert outcome == "exit 2", msg
        assert msg.startswith("motes: error: ") and "\n" not in msg and "Traceback" not in msg, msg
    elif case.kind == "error":
        assert raised is not None and issubclass(raised, case.exc), (outcome, msg)
    else:
        assert outcome.endswith("Warning"), (outcome, msg)
    assert all(w in msg for w in case.words), msg


def table() -> str:
    import tempfile

    rows = ["| # | input | outcome | message |", "|---|---|---|---|"]
    for i, case in enumerate(CASES, 1):
        with tempfile.TemporaryDirectory() as d:
            outcome, msg, _ = run_case(case, pathlib.Path(d))
        where = "`motes render`" if case.kind == "cli" else "API"
        msg = msg.replace(d, "<tmp>").replace('failed to instantiate medium plugin of type "discrete": ', "")
        msg = msg.replace("|", "\\|")
        rows.append(f"| {i} | {case.what} ({where}) | {outcome} | {msg} |")
    return "\n".join(rows)


def test_core_errors_are_motes_errors_naming_argument_and_value():
    """One error type from the core (issue 12): a ValueError subclass carrying the argument and value."""
    with pytest.raises(motes.MotesError) as e:
        motes.cross_sections([-1.0], 0.55, 1.33)
    assert isinstance(e.value, ValueError)
    assert e.value.argument == "radius_um" and e.value.value == -1.0
    with pytest.raises(motes.MotesError) as e:
        motes.phase_function([1.0], 0.55, 1.33, [4.0])
    assert e.value.argument == "theta" and e.value.value == 4.0


if __name__ == "__main__":
    sys.exit(print(table()))
