"""Hostile parameters (issue 44, core parameters and memory): numbers at and beyond their ranges (0, negative,
NaN, inf, 1e308, 2^63, integers given as floats), overflowing products and a memory limit. Each row of ``CASES``
is one input with the outcome it must get: one line naming the parameter (``motes render``: exit status 2, no
traceback), an exception from the Python API naming it, a warning, or a documented behaviour (a value checked
by ``check``). Nothing may abort, hang or render silently wrong. The hypothesis tests below sweep the checks
over full numeric ranges, endpoints included.

    .venv/bin/python tests/test_hostile_params.py     # prints the table (runs every case)
"""

from __future__ import annotations

import json
import pathlib
from fractions import Fraction
import resource
import subprocess
import sys
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import motes
from motes import _memory, _motes
from motes.discrete import (MAX_GRAIN_DEPTH, DiscreteMedium, _settings, checked_grain_depth, implausible_wavelengths,
                            species_shares)

from conftest import hsettings

mi = pytest.importorskip("mitsuba")

from test_malformed import Case, run_case  # noqa: E402  (the table's runner: a scene through `motes render`)
from test_plugin_inputs import load  # noqa: E402  (a discrete medium of 200 grains, from a dict)

MONO = {"type": "monodisperse", "radius_um": 5}
#: The address-space limit of the issue's report (``ulimit -v`` 1.5 GB).
RLIMIT_AS_BYTES = 1_500_000_000
#: A procedural cloud in the unit cube whose 50 um grains stay discrete (they have bricks).
PROCEDURAL = {"storage": "procedural", "count": 1000, "radius_median": 50.0,
              "to_world": '<transform name="to_world"><scale value="1, 1, 1"/></transform>'}


@dataclass
class Hostile(Case):
    """A row: ``Case``'s kinds, and "renders" (``motes render`` exits 0: a documented behaviour), "value"
    (``call`` returns the outcome's text, which ``check`` accepts) and "rlimit" (``code`` run by a fresh
    Python under RLIMIT_AS = ``RLIMIT_AS_BYTES``: its last line). ``absent``: words the message must not hold."""

    absent: list[str] = field(default_factory=list)
    check: Callable[[str], bool] | None = field(default=None, repr=False)
    code: str = ""


def _species(*shares) -> str:
    return json.dumps([{"psd": MONO, "eta": 1.5, "share": s} for s in shares])


def _generated_species_counts(shares, n=2000) -> str:
    """The species counts of a generated cloud of ``n`` grains whose species have ``shares``."""
    psd = motes.Monodisperse(5.0)._core
    _, _, sidx = _motes.generate_cloud(n, [-1.0] * 3, [1.0] * 3, "uniform", [], 0, [psd] * len(shares),
                                       [float(s) for s in shares], 0, np.eye(4)[:3].tolist())
    return f"species counts {np.bincount(sidx, minlength=len(shares)).tolist()} of {n}"


def _even(text: str) -> bool:
    counts = json.loads(text.split("counts ")[1].split(" of")[0])
    return abs(counts[0] - counts[1]) < 6 * np.sqrt(sum(counts) / 4)  # 6 binomial sigmas of an even split


def _procedural(**kw):
    args = dict(count=1000.0, species=[motes.Species(motes.LogNormal(20.0, 1.5), 1.33)], shares=[1.0],
                wavelength_um=[0.532], size_bins=1, scale_m=1e-3)
    return DiscreteMedium.procedural(**{**args, **kw})


def _moved(**kw) -> str:
    args = dict(velocity=[0.0, 0.0, 0.0], turbulence=0.0, turbulence_scale=1.0, seed=0, time=1.0, wrap_to_world=None)
    args.update(kw)
    pos = _motes.move_grains(np.array([0.5, 0.2, -0.3]), *args.values())
    return f"moved to {pos.tolist()}"


def _phase_minimum(eta: float) -> str:
    b = motes.bulk_properties(motes.Species(motes.Monodisperse(5.0), eta), 1.0, [0.532], cache=False,
                              theta=np.linspace(0, np.pi, 721), truncate_below_rad=0.0313)
    return f"sigma_t {b['sigma_t'][0]:.3g} /m, phase minimum {b['phase'].min():.3g}"


def _medium_in_nanometres():
    sp = motes.Species(motes.Monodisperse(20.0), 1.33)
    pos = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    DiscreteMedium(pos, np.full(50, 20.0), np.zeros(50, int), sp, [630.0, 532.0, 467.0], size_bins=1, scale_m=1e-3)


#: A medium of 10^4 grains of 0.05 um (narrower than the cells: each grid cell its own) at the largest
#: cells_per_particle its grid takes (2e4: 2e8 cells, 3 GiB to build) under
#: the issue's limit: refused by the estimate (ESTIMATE), or with the estimate switched off by the core's
#: allocation (a MemoryError, not an abort). The Python API, as the plugin builds it (no Mitsuba to start).
UNDER_LIMIT = """
import sys, numpy as np, motes
from motes import _memory, discrete
if "ESTIMATE" == "off":
    _memory.require_medium = lambda *a, **k: None
n = 10000
pos = np.random.default_rng(0).uniform(-1, 1, (n, 3))
try:
    discrete.DiscreteMedium(pos, np.full(n, 0.05), np.zeros(n, int), motes.Species(motes.Monodisperse(0.05), 1.33),
                            [0.532], size_bins=1, scale_m=1e-3, cells_per_particle=2e4, storage="full")
    print("no error")
except MemoryError as e:
    print("MemoryError:", e)
    sys.exit(2)
"""

CASES = [
    # Memory: every large allocation estimated first, against the limits that apply; none capped without a word.
    Hostile("cells_per_particle_huge", "cells_per_particle = 1e15 (used to be capped at 2e8 cells silently, then abort "
            "under ulimit -v)", "cli", ["cells_per_particle", "(0, 1000000] for 200 particles"],
            {"cells_per_particle": 1e15}),
    Hostile("cells_per_particle_under_rlimit", "cells_per_particle = 2e4 for 10^4 grains (2e8 cells) under ulimit -v "
            "1.5 GB", "rlimit", ["MemoryError", "cells_per_particle = 20000", "ulimit -v"],
            code=UNDER_LIMIT.replace("ESTIMATE", "on")),
    Hostile("grid_allocation_fails", "the same grid with the estimate switched off (the core's allocation fails)",
            "rlimit", ["MemoryError", "out of memory", "cells_per_particle"], code=UNDER_LIMIT.replace("ESTIMATE", "off")),
    Hostile("grid_cells_per_particle_api", "ParticleGrid(..., cells_per_particle=1e15)", "error",
            ["cells_per_particle", "(0, 20000000] for 10 particles"],
            call=lambda: motes.ParticleGrid(np.random.default_rng(0).random((10, 3)), np.ones(10), np.ones(10),
                                            cells_per_particle=1e15), exc=ValueError),
    Hostile("procedural_cells_per_particle", "storage = procedural, cells_per_particle = 1e6 (a brick's grid)", "cli",
            ["cells_per_particle", "bricks"], {**PROCEDURAL, "cells_per_particle": 1e6}),
    # Index-matched grains, rounding at the source of a phase table.
    Hostile("eta_equals_eta_medium", "eta = 1 (eta_medium 1: used to fail after 36 s of tables on f = -4e-17)", "cli",
            ["eta = 1", "eta_medium = 1", "neither scatter nor absorb"], {"eta": 1.0}),
    Hostile("eta_equals_eta_medium_133", "eta = 1.33, eta_medium = 1.33", "cli", ["eta", "eta_medium"],
            {"eta": 1.33, "eta_medium": 1.33}),
    Hostile("cross_sections_index_matched", "cross_sections(5, 0.532, eta=1): no scattering, exactly", "value",
            ["ext 0.0"], call=lambda: f"ext {float(motes.cross_sections(5.0, 0.532, 1.0)['ext'])}",
            check=lambda m: m == "ext 0.0"),
    Hostile("phase_near_index_matched", "bulk_properties at eta = 1.0001 (a weak, sensible medium)", "value",
            ["phase minimum"], call=lambda: _phase_minimum(1.0001),
            check=lambda m: float(m.split("minimum ")[1]) >= 0 and float(m.split()[1]) > 0),
    # Ranges stated, and values shown as given.
    Hostile("grain_depth_2_32", "grain_depth = 2^32 (its range used to read \">= 1\")", "cli",
            ["grain_depth", "[1, 4294967295]"], {"grain_depth": 2**32}),
    Hostile("grain_depth_float", "grain_depth = 3.0 (an integer given as a float)", "renders", [], {"grain_depth": 3.0}),
    Hostile("count_1e308", "count = 1e308 (used to print 309 digits)", "cli", ["count = 1e+308", "[1, 1e9]"],
            {"count": 1e308}, check=lambda m: len(m) < 400),
    Hostile("count_nan", "count = nan", "cli", ["count", "an integer", "nan"], {"count": float("nan")}),
    Hostile("count_inf", "count = inf", "cli", ["count", "an integer", "inf"], {"count": float("inf")}),
    Hostile("count_2_63", "count = 2^63 (beyond Mitsuba's integers: its parser names the line)", "cli",
            ["could not parse integer value", "9223372036854775808"], {"count": 2**63}),
    Hostile("count_fraction", "count = 300.5", "cli", ["count", "an integer", "300.5"], {"count": 300.5}),
    Hostile("count_float", "count = 300.0 (an integer given as a float)", "renders", [], {"count": 300.0}),
    Hostile("size_bins_nan", "size_bins = nan", "cli", ["size_bins", "an integer"], {"size_bins": float("nan")}),
    Hostile("size_bins_1e308", "size_bins = 1e308", "cli", ["size_bins = 1e+308", "[1, 4096]"], {"size_bins": 1e308}),
    Hostile("size_bins_negative", "size_bins = -3", "cli", ["size_bins", "[1, 4096]"], {"size_bins": -3}),
    Hostile("continuous_count_nan", "continuous_count = nan", "cli", ["continuous_count"],
            {"continuous_count": float("nan")}),
    Hostile("continuous_count_negative", "continuous_count = -1", "cli", ["continuous_count"],
            {"continuous_count": -1.0}),
    Hostile("continuous_count_inf", "continuous_count = inf (documented: every grain walked)", "renders", [],
            {"continuous_count": float("inf")}),
    Hostile("query_radius_nan", "query_radius = nan", "cli", ["query_radius"], {"query_radius": float("nan")}),
    Hostile("query_radius_inf", "query_radius = inf (a warning used to come first)", "cli", ["query_radius"],
            {"query_radius": float("inf")}),
    Hostile("query_radius_1e308", "query_radius = 1e308 (disks of zero depth: an empty medium)", "cli",
            ["query_radius", "3.4e38"], {"query_radius": 1e308}),
    Hostile("footprint_k_nan", "footprint_k = nan", "cli", ["footprint_k", "(0, 2]"],
            {"footprint_k": float("nan"), "fov": 40.0, "film_width": 64, "z_med": 10.0}),
    Hostile("footprint_k_1e308", "footprint_k = 1e308", "cli", ["footprint_k", "(0, 2]"],
            {"footprint_k": 1e308, "fov": 40.0, "film_width": 64, "z_med": 10.0}),
    Hostile("scale_m_tiny", "scale_m = 1e-300 (grains 1e295 units wide: used to blame c_ext)", "cli",
            ["scale_m = 1e-300", "metres per scene unit"], {"scale_m": 1e-300}),
    # Overflowing products: the parameter that overflows is named.
    Hostile("turbulence_overflow", "turbulence = 1e308 (used to blame velocity)", "cli", ["turbulence", "drift"],
            {"turbulence": 1e308, "time": 1.0}, absent=["velocity"]),
    Hostile("velocity_time_overflow", "velocity = (1e30, 0, 0), time = 1e300", "error", ["velocity", "time", "overflows"],
            call=lambda: load(velocity=mi.ScalarVector3f(1e30, 0, 0), time=1e300), exc=Exception),
    Hostile("procedural_velocity_overflow", "the same with storage = procedural (used to read \"to_world must be a "
            "finite 4x4 matrix\")", "error", ["velocity", "time", "overflows"],
            call=lambda: load(storage="procedural", to_world=mi.ScalarTransform4f(), velocity=mi.ScalarVector3f(1e30, 0, 0),
                              time=1e300), exc=Exception, absent=["4x4"]),
    Hostile("procedural_to_world_overflow", "storage = procedural, to_world scale 1e300", "cli", ["to_world"],
            {**PROCEDURAL, "to_world": '<transform name="to_world"><scale value="1e300, 1e300, 1e300"/></transform>'}),
    Hostile("procedural_box_overflow", "DiscreteMedium.procedural(box=+-1e200): its volume overflows", "error",
            ["box", "volume"], call=lambda: _procedural(box=((-1e200,) * 3, (1e200,) * 3)), exc=ValueError),
    Hostile("procedural_to_world_api", "DiscreteMedium.procedural(to_world=diag(1e200)): |det| overflows", "error",
            ["to_world", "determinant"], call=lambda: _procedural(to_world=np.diag([1e200, 1e200, 1e200, 1.0])),
            exc=ValueError),
    Hostile("procedural_turbulence", "DiscreteMedium.procedural(turbulence=1e308)", "error", ["turbulence"],
            call=lambda: _procedural(turbulence=1e308, time_s=1.0), exc=ValueError, absent=["velocity"]),
    Hostile("move_turbulence_scale", "move_grains(turbulence_scale=1e-300): a drift finer than doubles resolve", "error",
            ["turbulence_scale"], call=lambda: _moved(turbulence=1.0, turbulence_scale=1e-300), exc=ValueError),
    Hostile("move_time", "move_grains(turbulence=1, time=1e300)", "error", ["time", "1e12"],
            call=lambda: _moved(turbulence=1.0, time=1e300), exc=ValueError),
    Hostile("shares_overflow", "species shares 1e308 and 1e308 (their sum overflows: used to give [0, 1000])", "value",
            ["species counts"], call=lambda: _generated_species_counts([1e308, 1e308]), check=_even),
    Hostile("shares_overflow_plugin", "the same through the plugin's species", "renders", [],
            {"species": _species(1e308, 1e308), "count": 1000}),
    Hostile("shares_overflow_procedural", "the same in a procedural cloud (used to read \"bin_edges_um = 0\")", "value",
            ["particles"], call=lambda: f"particles {len(_procedural(species=[motes.Species(motes.Monodisperse(20.0), 1.33)] * 2, shares=[1e308, 1e308]))}",
            check=lambda m: m.startswith("particles")),
    Hostile("share_inf", "a species share = Infinity", "cli", ["share"], {"species": _species(float("inf"), 1.0)}),
    # Units.
    Hostile("wavelengths_in_nm", "wavelengths = \"630, 532, 467\" (nanometres)", "cli",
            ["wavelengths", "nanometres", "0.63, 0.532, 0.467"], {"wavelengths": "630, 532, 467"}),
    Hostile("wavelength_um_in_nm_api", "DiscreteMedium(..., wavelength_um=[630, 532, 467])", "warning",
            ["wavelength_um", "nanometres"], call=_medium_in_nanometres),
]


def run(case: Hostile, tmp: pathlib.Path) -> tuple[str, str, type | None]:
    """(outcome class, message, exception type), as ``test_malformed.run_case`` and for this file's kinds."""
    if case.kind == "rlimit":
        def limit():
            resource.setrlimit(resource.RLIMIT_AS, (RLIMIT_AS_BYTES, RLIMIT_AS_BYTES))

        r = subprocess.run([sys.executable, "-c", case.code], capture_output=True, text=True, timeout=300,
                           preexec_fn=limit)
        lines = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip() and not ln.startswith(("motes: ", "  ["))
                 or ln.startswith("motes: error")]
        return (f"exit {r.returncode}", lines[-1] if lines else "", None)
    if case.kind == "value":
        return ("value", case.call(), None)
    kind = "cli" if case.kind == "renders" else case.kind
    outcome, msg, raised = run_case(Case(case.name, case.what, kind, case.words, case.medium, case.call, case.exc), tmp)
    # Less the load's progress lines (a medium that fills its shapes is built, and fails, after them).
    return outcome, "\n".join(ln for ln in msg.splitlines() if not ln.startswith("motes:   ")), raised


def test_cases_are_distinct():
    assert len(CASES) >= 40 and len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_hostile_input(case: Hostile, tmp_path):
    outcome, msg, raised = run(case, tmp_path)
    if case.kind in ("cli", "rlimit"):
        assert outcome == "exit 2", msg
        assert "\n" not in msg and "Traceback" not in msg, msg
        assert case.kind == "rlimit" or msg.startswith("motes: error: "), msg
    elif case.kind == "renders":
        assert outcome == "exit 0" and "error" not in msg, msg
    elif case.kind == "error":
        assert raised is not None and issubclass(raised, case.exc), (outcome, msg)
    elif case.kind == "warning":
        assert outcome.endswith("Warning"), (outcome, msg)
    assert all(w in msg for w in case.words), msg
    assert not any(w in msg for w in case.absent), msg
    assert case.check is None or case.check(msg), msg


def table() -> str:
    import tempfile

    rows = ["| # | input | outcome | message |", "|---|---|---|---|"]
    for i, case in enumerate(CASES, 1):
        with tempfile.TemporaryDirectory() as d:
            outcome, msg, _ = run(case, pathlib.Path(d))
        where = {"cli": "`motes render`", "renders": "`motes render`", "rlimit": "`ulimit -v`"}.get(case.kind, "API")
        msg = msg.replace(d, "<tmp>").replace('failed to instantiate medium plugin of type "discrete": ', "")
        msg = msg.replace("|", "\\|").replace("\n", " ")
        rows.append(f"| {i} | {case.what} ({where}) | {outcome} | {msg} |")
    return "\n".join(rows)


# -- The checks over full numeric ranges -------------------------------------------------------------------------
#: Every float, the endpoints and specials included.
ANY_FLOAT = st.one_of(st.sampled_from([0.0, -0.0, 5e-324, -5e-324, 1e-300, 1.0, 2.0**32, 1e308, 1.7976931348623157e308,
                                       float("inf"), -float("inf"), float("nan")]),
                      st.floats(allow_nan=True, allow_infinity=True))
#: Every integer Mitsuba's properties hold (int64), the endpoints included.
ANY_INT64 = st.one_of(st.sampled_from([0, 1, -1, 2**31, 2**32 - 1, 2**32, 10**9, 10**9 + 1, 2**63 - 1, -(2**63)]),
                      st.integers(-(2**63), 2**63 - 1))


def _core_check(**kw):
    """The core's checks of a medium's settings (``check_discrete_inputs``) for 10 particles in the unit cube;
    None where they pass, else the argument named."""
    pos = np.random.default_rng(0).random((10, 3))
    settings = _settings(**{"query_radius": 0.0, "tau_max": 1.0, "cells_per_particle": 0.125,
                            "continuous_count": 16.0, **kw})
    try:
        _motes.check_discrete_inputs(pos.ravel(), np.ones(10), settings)
    except motes.MotesError as e:
        assert str(e).startswith(f"invalid {e.argument} = ") and "must be" in str(e), str(e)
        return e.argument
    return None


@hsettings(300)
@given(ANY_FLOAT)
def test_cells_per_particle_takes_exactly_its_stated_range(v):
    """(0, 2e8 / particles]: beyond it an error naming it (the grid's cells were capped without a word)."""
    assert _core_check(cells_per_particle=v) == (None if 0 < v <= 2e8 / 10 else "cells_per_particle")


@hsettings(300)
@given(ANY_FLOAT)
def test_query_radius_takes_exactly_its_stated_range(v):
    """[0, 3.4e38] (the renderer's single precision): beyond it disks have no depth, or no size."""
    assert _core_check(query_radius=v) == (None if 0 <= v <= float(np.finfo(np.float32).max) else "query_radius")


@hsettings(200)
@given(ANY_FLOAT, st.sampled_from(["tau_max", "continuous_count"]))
def test_tau_max_and_continuous_count_take_positive_values_and_inf(v, name):
    assert _core_check(**{name: v}) == (None if v > 0 else name)


def _plugin_problems(**values) -> list[str]:
    """The problems ``_read_parameters`` finds with a medium's ``values`` (no optics, no particles)."""
    from motes.plugins import discrete_medium as dm

    motes.set_variant("scalar_rgb")
    props = mi.Properties("discrete")
    for k, v in values.items():
        props[k] = v
    return dm._read_parameters(props)[1]


@hsettings(300)
@given(st.sampled_from(["size_bins", "grain_depth", "seed", "film_width"]), st.one_of(ANY_INT64, ANY_FLOAT))
def test_integer_parameters_take_exactly_their_range(name, v):
    """An integer parameter (or a float holding an integer) inside its stated range passes; anything else is one
    problem naming the parameter and showing the value as given."""
    lo, hi = {"size_bins": (1, 4096), "grain_depth": (1, MAX_GRAIN_DEPTH), "seed": (0, 2**64 - 1),
              "film_width": (1, float("inf"))}[name]
    extra = {"footprint_k": 0.5, "fov": 40.0, "z_med": 10.0} if name == "film_width" else {}
    problems = [b for b in _plugin_problems(**{name: v}, **extra) if name in b]
    integral = isinstance(v, int) or (np.isfinite(v) and float(v).is_integer())
    if integral and lo <= int(v) <= hi:
        assert problems == []
    else:
        assert len(problems) == 1 and repr(v) in problems[0], problems


@hsettings(200)
@given(st.one_of(ANY_INT64, ANY_FLOAT))
def test_count_takes_its_range_or_says_the_memory(v):
    """count in [1, 1e9], integral: accepted, or a MemoryError naming it where it would not fit."""
    try:
        problems = [b for b in _plugin_problems(count=v) if "count" in b]
    except MemoryError as e:
        assert "count" in str(e) and "GiB" in str(e)
        problems = []
    integral = isinstance(v, int) or (np.isfinite(v) and float(v).is_integer())
    if integral and 1 <= int(v) <= 10**9:
        assert problems == []
    else:
        assert len(problems) == 1 and repr(v) in problems[0] and len(problems[0]) < 300, problems


@hsettings(300)
@given(st.one_of(st.integers(-(2**70), 2**70), ANY_FLOAT, st.booleans()))
def test_grain_depth_range_is_stated(v):
    if isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 2**32 - 1:
        assert checked_grain_depth(v) == v
    else:
        with pytest.raises(ValueError, match=r"grain_depth.*\[1, 4294967295\]"):
            checked_grain_depth(v)


@hsettings(300)
@given(st.lists(ANY_FLOAT, min_size=1, max_size=4))
def test_shares_are_relative_and_never_overflow(shares):
    """Shares: finite, >= 0, one > 0, else a ValueError naming share; the result is finite with the same
    proportions (1e308 and 1e308: an even split)."""
    species = [motes.Species(motes.Monodisperse(1.0), 1.5)] * len(shares)
    w = np.array(shares)
    if not (np.all(np.isfinite(w) & (w >= 0)) and np.any(w > 0)):
        with pytest.raises(ValueError, match="share"):
            species_shares(species, shares)
        return
    out = species_shares(species, shares)
    assert all(np.isfinite(out)) and max(out) == 1.0 and np.isfinite(sum(out))
    exact = [float(Fraction(x) / Fraction(float(w.max()))) for x in shares]  # rational arithmetic: no overflow
    assert out == exact, (out, exact)


@hsettings(40)
@given(st.floats(0, 1.7976931348623157e308), st.floats(0, 1.7976931348623157e308))
def test_generated_species_follow_shares_of_any_size(a, b):
    """The core's species draw by shares of any magnitude: the counts follow a / (a + b) computed without
    overflow (6 binomial sigmas)."""
    if a == 0 and b == 0:
        return
    n = 1000
    text = _generated_species_counts([a, b], n)
    first = json.loads(text.split("counts ")[1].split(" of")[0])[0]
    p = 1.0 / (1.0 + b / a) if a > 0 else 0.0
    assert abs(first - n * p) <= 6 * np.sqrt(n * p * (1 - p)) + 1e-9, (a, b, text)


@hsettings(300)
@given(ANY_FLOAT)
def test_wavelengths_outside_10nm_to_100um_are_named(v):
    problem = implausible_wavelengths([v], "wavelength_um")
    if 0.01 <= v <= 100:
        assert problem is None
    else:
        assert problem is not None and problem.startswith("wavelength_um = ") and "nanometres" in problem


@hsettings(200)
@given(st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT, ANY_FLOAT))
def test_moving_grains_end_somewhere_or_the_cause_is_named(args):
    """velocity, turbulence, turbulence_scale and time over every float: the grains end at finite positions, or
    one error names the input that would have sent them nowhere (or stopped their drift)."""
    v, turbulence, scale, t = args
    try:
        pos = _motes.move_grains(np.array([0.5, 0.2, -0.3, 2.0, 1.0, 0.0]), [v, 0.0, 0.0], turbulence, scale, 1, t, None)
    except motes.MotesError as e:
        assert e.argument in ("velocity", "turbulence", "turbulence_scale", "time"), str(e)
        return
    assert np.all(np.isfinite(pos))


# -- The memory available: every limit that applies ---------------------------------------------------------------
def test_memory_available_honours_rlimit_as(monkeypatch):
    """RLIMIT_AS (``ulimit -v``) less the address space in use bounds the memory available, and says so."""
    used = _memory._proc_status_bytes("VmSize")
    if used is None:
        pytest.skip("needs Linux /proc")
    real = resource.getrlimit
    monkeypatch.setattr(resource, "getrlimit", lambda r: (used + 2**30, resource.RLIM_INFINITY)
                        if r == resource.RLIMIT_AS else real(r))
    room, source = _memory.available()
    assert 0 < room <= 2**30 and "ulimit -v" in source
    with pytest.raises(MemoryError, match=r"count = 9 needs about 2\.0 GiB.*ulimit -v"):
        _memory.require(2 * 2**30, "count = 9")


def test_memory_available_honours_the_cgroup(tmp_path):
    """A memory cgroup's limit less its usage bounds it (v2 and v1, at the cgroup's path or the mount's root)."""
    proc = tmp_path / "cgroup"
    for version, (limit, usage), line in (("v2", ("memory.max", "memory.current"), "0::/job\n"),
                                          ("v1", ("memory.limit_in_bytes", "memory.usage_in_bytes"), "4:memory:/job\n")):
        mount = tmp_path / version
        job = mount / "job" if version == "v2" else mount / "memory" / "job"
        job.mkdir(parents=True)
        (job / limit).write_text(str(3 * 2**30))
        (job / usage).write_text(str(2**30))
        proc.write_text(line)
        assert _memory._cgroup_room(str(proc), str(mount)) == 2 * 2**30
        (job / limit).write_text("max" if version == "v2" else str(2**63 - 4096))
        assert _memory._cgroup_room(str(proc), str(mount)) is None

if __name__ == "__main__":
    print(table())
