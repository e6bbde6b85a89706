"""Paper Fig. 3 and Fig. 21 (App. E): the extinction cross section C_t against the radius r.

    .venv/bin/python scripts/figures/fig3_extinction.py [--out out/] [--quick]

Mie vs GOA with p_max = 1 and 3 (``motes.cross_sections(..., method="goa", p_max=1|3)["ext"]``) for
eta = 1.33, lambda = 0.6 um, r log-spaced from 0.1 to 100 um (3000 radii; 600 with --quick), plus the
paper-verbatim GOA (``regularise=False, edge_correction=False``, dashed). ``cross_sections`` clamps GOA's
C_ext at >= C_abs (= 0 here); where Eq. 12 itself is negative the raw value of
``motes.goa_extinction_efficiency`` is recorded as well.

Outputs: ``fig3_extinction.png`` (C_t, Q_t zoom on the ripple, relative error vs Mie),
``fig21_ct_relmse_p1_p3.png`` (Eq. 38 between p = 1 and p = 3) and ``fig3_extinction.json``.
Prints: median / 95th percentile of |C_GOA - C_Mie| / C_Mie in the r-bands [1, 10) and [10, 100] um,
and the maximum over r > 1 um of RelMSE{C_t} between p = 1 and p = 3 (paper: < 1e-5).
"""

from __future__ import annotations

import sys
import pathlib

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import numpy as np  # noqa: E402

import _common as C  # noqa: E402

ETA = 1.33

# (key, label, kwargs of cross_sections)
VARIANTS = [
    ("ours_p3", "GOA p=3 (ours)", dict(p_max=3)),
    ("ours_p1", "GOA p=1 (ours)", dict(p_max=1)),
    ("paper_p3", "GOA p=3 (paper verbatim)", dict(p_max=3, regularise=False, edge_correction=False)),
    ("paper_p1", "GOA p=1 (paper verbatim)", dict(p_max=1, regularise=False, edge_correction=False)),
]
BANDS = [(1.0, 10.0, "[1, 10)"), (10.0, 100.0 + 1e-9, "[10, 100]")]


def compute(motes, r):
    """C_t of Mie and of each GOA variant (clamped, and Eq. 12 unclamped) at the radii r, with their timings."""
    area = np.pi * r**2
    alpha = np.asarray(motes.size_parameter(r, C.LAM))
    timings = {}
    t, cs = C.best_of(lambda: motes.cross_sections(r, C.LAM, ETA, method="mie"), 1)
    timings["mie"] = t
    c_mie = cs["ext"]
    c = {}
    raw = {}
    for key, _, kw in VARIANTS:
        t, cs = C.best_of(lambda kw=kw: motes.cross_sections(r, C.LAM, ETA, method="goa", **kw), 1)
        timings[key] = t
        c[key] = cs["ext"]
        raw[key] = motes.goa_extinction_efficiency(alpha, ETA, **kw) * area  # unclamped Eq. 12
    return c_mie, c, raw, timings


def band_table(r, relerr, n: int) -> dict:
    """Print the Fig. 3 table (error vs Mie per r band, p = 3 variants); return its statistics."""
    rows = []
    stats = {}
    for key, label, _ in VARIANTS:
        if key.endswith("p1"):
            continue
        for lo, hi, name in BANDS:
            sel = (r >= lo) & (r < hi)
            e = relerr[key][sel]
            stats[f"{key} {name}"] = dict(median=float(np.median(e)), p95=float(np.percentile(e, 95)), max=float(e.max()), n=int(sel.sum()))
            rows.append([label, name, np.median(e), np.percentile(e, 95), e.max()])
    C.print_table(
        f"Fig. 3: relative C_t error |C_GOA − C_Mie|/C_Mie, eta = {ETA}, lambda = {C.LAM} µm, {n} log-spaced radii in [0.1, 100] µm",
        ["variant", "r band (µm)", "median", "95th pct", "max"],
        rows,
    )
    return stats


def fig21_table(r, c, raw):
    """Print the Fig. 21 table (RelMSE{C_t} between p = 1 and p = 3); return (RelMSE ours, RelMSE paper, r > 1 mask)."""
    rm_ours = C.relmse_scalar(c["ours_p3"], c["ours_p1"])
    rm_paper = C.relmse_scalar(raw["paper_p3"], raw["paper_p1"])
    big = r > 1.0
    rows21 = [
        ["ours (regularised + edge)", rm_ours[big].max(), r[big][np.argmax(rm_ours[big])], rm_ours.max(), r[np.argmax(rm_ours)], bool(rm_ours[big].max() < 1e-5)],
        ["paper verbatim", rm_paper[big].max(), r[big][np.argmax(rm_paper[big])], rm_paper.max(), r[np.argmax(rm_paper)], bool(rm_paper[big].max() < 1e-5)],
    ]
    C.print_table(
        "Fig. 21 (App. E): RelMSE{C_t} = (C_t^{p=3} − C_t^{p=1})² / (C_t^{p=3})², eta = 1.33 (acceptance: max over r > 1 µm < 1e-5)",
        ["GOA", "max over r > 1 µm", "at r (µm)", "max over all r", "at r (µm)", "< 1e-5 for r > 1"],
        rows21,
    )
    return rm_ours, rm_paper, big


def plot_fig3(plt, out: pathlib.Path, r, c_mie, c, raw, relerr, rel_raw) -> None:
    """``fig3_extinction.png``: C_t, Q_t zoomed on the ripple, relative error vs Mie."""
    area = np.pi * r**2
    colors = {"mie": "tab:blue", "ours_p3": "tab:red", "ours_p1": "tab:green", "paper_p3": "k", "paper_p1": "0.5"}
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    ax = axes[0]
    ax.loglog(r, c_mie, color=colors["mie"], lw=1.2, label="Lorenz–Mie")
    ax.loglog(r, c["ours_p3"], color=colors["ours_p3"], lw=0.9, label="GOA p=3 (ours)")
    ax.loglog(r, c["ours_p1"], color=colors["ours_p1"], lw=0.9, ls=":", label="GOA p=1 (ours)")
    pp = np.where(raw["paper_p3"] > 0, raw["paper_p3"], np.nan)
    ax.loglog(r, pp, color=colors["paper_p3"], lw=0.8, ls="--", label="GOA p=3 (paper verbatim)")
    C.label(ax, "r (µm)", "C_t (µm²)", f"(a) C_t vs r, η={ETA}, λ={C.LAM} µm", legend=8)

    ax = axes[1]
    zoom = (r >= 0.1) & (r <= 10.0)
    ax.plot(r[zoom], c_mie[zoom] / area[zoom], color=colors["mie"], lw=1.2, label="Lorenz–Mie")
    ax.plot(r[zoom], c["ours_p3"][zoom] / area[zoom], color=colors["ours_p3"], lw=0.9, label="GOA p=3 (ours)")
    ax.plot(r[zoom], c["ours_p1"][zoom] / area[zoom], color=colors["ours_p1"], lw=0.9, ls=":", label="GOA p=1 (ours)")
    ax.plot(r[zoom], raw["paper_p3"][zoom] / area[zoom], color=colors["paper_p3"], lw=0.8, ls="--", label="GOA p=3 (paper, unclamped)")
    ax.set_xscale("log")
    ax.set_ylim(-1, 6)
    ax.axhline(2, color="0.6", lw=0.6)
    C.label(ax, "r (µm)", "Q_t = C_t / πr²", "(b) ripple structure, r ≤ 10 µm (efficiency)", legend=8)

    ax = axes[2]
    ax.loglog(r, rel_raw["paper_p3"], color=colors["paper_p3"], lw=0.6, alpha=0.8, label="paper verbatim p=3")
    ax.loglog(r, relerr["ours_p3"], color=colors["ours_p3"], lw=0.6, alpha=0.9, label="ours p=3")
    ax.set_ylim(1e-6, 10)
    C.label(ax, "r (µm)", "|C_GOA − C_Mie| / C_Mie", "(c) relative error vs Lorenz–Mie", legend=8)
    C.save_fig(fig, out / "fig3_extinction.png")


def plot_fig21(plt, out: pathlib.Path, r, rm_ours, rm_paper) -> None:
    """``fig21_ct_relmse_p1_p3.png``: RelMSE{C_t} between p = 1 and p = 3 against r."""
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    ax.loglog(r, np.maximum(rm_ours, 1e-20), color="tab:red", lw=0.8, label="ours (regularised + edge term)")
    ax.loglog(r, np.maximum(rm_paper, 1e-20), color="k", lw=0.6, ls="--", label="paper verbatim")
    ax.axhline(1e-5, color="0.5", lw=0.8, ls=":", label="1e-5")
    ax.set_ylim(1e-14, 10)
    C.label(ax, "r (µm)", "RelMSE{C_t} between p=1 and p=3 (Eq. 38)", f"Fig. 21: η={ETA}, λ={C.LAM} µm", legend=8)
    C.save_fig(fig, out / "fig21_ct_relmse_p1_p3.png")


def main() -> None:
    args, out, sw, motes = C.start(__doc__)

    n = 600 if args.quick else 3000
    r = np.geomspace(0.1, 100.0, n)
    c_mie, c, raw, timings = compute(motes, r)
    relerr = {k: np.abs(c[k] - c_mie) / c_mie for k in c}
    rel_raw = {k: np.abs(raw[k] - c_mie) / c_mie for k in raw}

    stats = band_table(r, relerr, n)
    rm_ours, rm_paper, big = fig21_table(r, c, raw)

    neg = {k: r[raw[k] <= 0].tolist() for k in raw}
    neg_summary = {k: (dict(count=len(v), r_min=min(v), r_max=max(v)) if v else dict(count=0)) for k, v in neg.items()}
    nonfinite = {k: int((~np.isfinite(c[k])).sum()) for k in c}
    nonfinite["mie"] = int((~np.isfinite(c_mie)).sum())
    print(f"radii where Eq. 12 (unclamped) gives C_t <= 0: {neg_summary}")
    print(f"non-finite C_t values: {nonfinite}")

    # cross-check: cross_sections ext == goa_extinction_efficiency * pi r^2 wherever positive
    pos = raw["ours_p3"] > 0
    consistency = float(np.max(np.abs(c["ours_p3"][pos] - raw["ours_p3"][pos]) / np.abs(raw["ours_p3"][pos])))

    plt = C.plt()
    plot_fig3(plt, out, r, c_mie, c, raw, relerr, rel_raw)
    plot_fig21(plt, out, r, rm_ours, rm_paper)

    C.finish(
        args, sw, out / "fig3_extinction.json",
        eta=ETA,
        wavelength_um=C.LAM,
        n_radii=n,
        band_stats=stats,
        fig21=dict(
            ours_max_relmse_r_gt_1=float(rm_ours[big].max()),
            paper_max_relmse_r_gt_1=float(rm_paper[big].max()),
            acceptance_lt_1e5=bool(rm_ours[big].max() < 1e-5),
        ),
        unclamped_eq12_nonpositive=neg_summary,
        nonfinite=nonfinite,
        cross_sections_vs_goa_extinction_efficiency_max_reldiff=consistency,
        timings_s=timings,
        curves=dict(r_um=r, c_mie=c_mie, **{f"c_{k}": v for k, v in c.items()}, c_paper_p3_unclamped=raw["paper_p3"]),
    )


if __name__ == "__main__":
    main()
