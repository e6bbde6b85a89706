"""White furnace of the `discrete` medium over the regimes where energy used to go missing (issue 9.1).

Non-absorbing particles (``albedo = 1``) in a box under a constant white environment render exactly 1 with
any unbiased estimator. Russian roulette is off (``rr_depth`` huge): each path's weight then stays near 1,
so a loss of a few per cent cannot hide in the noise. The grid spans grains small and large against
their spacing (radius / spacing from 0.01 to 1.5: from a haze to overlapping inclusion balls), the default
and a user query radius, and a rotated, non-uniformly scaled box; every variant is covered at the hardest
point. ``scripts/figures/furnace_grid.py`` runs the full grid with more samples.
"""

from __future__ import annotations

import pathlib
import sys

import pytest

import motes

mi = pytest.importorskip("mitsuba")
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "scripts"))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "scripts" / "figures"))
from furnace_grid import furnace_medium, render_furnace  # noqa: E402

# (count, radius / spacing): a sparse haze, grains a third of their spacing, overlapping inclusion balls.
REGIMES = [(20000, 0.01), (400, 0.3), (60, 1.5)]


@pytest.mark.filterwarnings("ignore:query_radius")
@pytest.mark.parametrize("count,ratio", REGIMES)
@pytest.mark.parametrize("query_radius", [None, 0.05])
@pytest.mark.parametrize("transform", ["identity", "rotated_scaled"])
def test_furnace_grid_llvm(count, ratio, query_radius, transform):
    motes.set_variant("llvm_ad_rgb")
    m, se = render_furnace(furnace_medium(count, ratio, query_radius), transform, 24, 32)
    assert abs(m - 1.0) < 3 * se + 1e-3, f"radius/spacing {ratio}, r_c {query_radius}, {transform}: {m:.4f} +- {se:.4f}"
    assert se < 0.02


@pytest.mark.parametrize("continuous_count", [None, float("inf")])
@pytest.mark.parametrize("variant,res,spp", [("scalar_rgb", 32, 32), ("scalar_spectral", 32, 32), ("llvm_ad_spectral", 24, 32)])
def test_furnace_dense_all_variants(variant, res, spp, continuous_count):
    """The hardest point (balls wider than the spacing, rotated and scaled box) in the other variants, as a
    user gets it (rays past a path's first event see the grains' continuous equivalent, issue 25) and
    exact (``continuous_count`` inf: every ray walks the grains)."""
    motes.set_variant(variant)
    med = furnace_medium(60, 1.5)
    if continuous_count is not None:
        med["continuous_count"] = continuous_count
    m, se = render_furnace(med, "rotated_scaled", res, spp)
    assert abs(m - 1.0) < 3 * se + 1e-3, f"{variant}: {m:.4f} +- {se:.4f}"
    assert se < 0.05
