"""The effect of each GOA regularisation (and of the edge term) measured against Lorenz-Mie.

    .venv/bin/python scripts/figures/singularities.py [--out out/] [--quick]

``regularise=False, edge_correction=False`` is the paper verbatim; the defaults are ours. lambda = 0.6 um.

(a) rainbow caustic: eta = 1.33, r = 10, 100 um, |S1| in the window 125-145 deg (primary rainbow at
    ~138 deg): RelMSE vs Mie on the 1800-angle grid, and max |S1| on a fine grid that contains the exact
    geometric rainbow angle (the paper's amplitude is infinite there).
(b) eta -> 1: C_ext(GOA)/C_ext(Mie) for eta = 1.0, 1.001, 1.01, 1.05, 1.1 and r = 1, 10, 100 um, ours vs
    paper (Eq. 12 unclamped, from ``motes.goa_extinction_efficiency``; ``cross_sections`` clamps at >= 0).
(c) theta -> 0 and pi: S1, S2 at theta = 0, 1e-6, pi - 1e-6, pi (continuity, finiteness, the symmetries
    S1(0) = S2(0) and S1(pi) = -S2(pi)) vs Mie, for eta = 1.33, 0.75, 1.5+0.01i and r = 1, 10, 100 um.
(d) glory: backward window 170-180 deg, RelMSE of (|S1|+|S2|)/2 vs Mie, regularised vs not (eta = 1.33 as
    asked; 0.75 and 1.5+0.01i added, where rays with p <= 3 do leave exactly backwards).
(e) edge term: see ``edge_term_study`` (also run alone by ``scripts/figures/edge_term.py``): mean C_ext error vs
    Mie with and without ``edge_correction`` for r in [10, 100] and [100, 1000] um, eta = 1.33, 1.5 (and
    0.75, where the code leaves the term out), and the ripple-averaged coefficient c of
    Q_ext ~ 2 + c x^(-2/3) from Mie over x in [200, 400] (Nussenzveig-Wiscombe: 1.9924 for eta > 1).

Outputs ``singularities.png``, ``edge_term.png`` and ``singularities.json``; prints one table per part.
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py

import numpy as np  # noqa: E402

import _common as C  # noqa: E402

NW_C = 1.9923861  # Nussenzveig & Wiscombe (1980) coefficient of x^(-2/3), eta > 1


def rainbow_angle(eta: float) -> float:
    """Primary (p = 2) geometric rainbow scattering angle, radians."""
    ci = np.sqrt((eta**2 - 1.0) / 3.0)
    ti = np.arccos(ci)
    tt = np.arcsin(np.sin(ti) / eta)
    dev = 4 * tt - 2 * ti - np.pi  # Eq. 5, p = 2
    return float(abs(dev))


def window(theta_deg, lo, hi):
    return (theta_deg >= lo) & (theta_deg <= hi)


# ---------------------------------------------------------------------------------------------- (a)
def part_a(motes, quick):
    eta = 1.33
    th = C.THETA
    deg = np.degrees(th)
    w = window(deg, 125, 145)
    t_rb = rainbow_angle(eta)
    fine = np.unique(np.concatenate([np.radians(np.linspace(125, 145, 4001 if quick else 20001)), [t_rb]]))
    rows, data = [], {}
    for r in (10.0, 100.0):
        m1, _ = motes.mie_amplitudes(r, C.LAM, eta, th)
        mf, _ = motes.mie_amplitudes(r, C.LAM, eta, fine)
        rec = dict(mie_max=float(np.abs(mf).max()))
        curves = dict(mie=np.abs(m1[w]))
        for reg in (True, False):
            g1, _ = motes.goa_amplitudes(r, C.LAM, eta, th, regularise=reg)
            gf, _ = motes.goa_amplitudes(r, C.LAM, eta, fine, regularise=reg)
            gr, _ = motes.goa_amplitudes(r, C.LAM, eta, np.array([t_rb]), regularise=reg)
            key = "ours" if reg else "paper"
            rec[key] = dict(relmse=C.relmse(np.abs(g1[w]), np.abs(m1[w])), max_fine=float(np.abs(gf).max()),
                            at_rainbow=float(np.abs(gr[0])), finite=bool(np.all(np.isfinite(gf))))
            curves[key] = np.abs(g1[w])
        data[r] = rec
        data[r]["curves"] = curves
        rows.append([r, rec["ours"]["relmse"], rec["paper"]["relmse"], rec["mie_max"], rec["ours"]["max_fine"],
                     rec["paper"]["max_fine"], rec["paper"]["at_rainbow"]])
    C.print_table(
        f"(a) rainbow caustic, eta = 1.33, |S1| in 125–145° (geometric rainbow {np.degrees(t_rb):.3f}°)",
        ["r (µm)", "RelMSE ours", "RelMSE paper", "max|S1| Mie", "max|S1| ours", "max|S1| paper (fine grid)", "|S1| paper at rainbow angle"],
        rows,
    )
    return dict(theta_window_deg=deg[w], rainbow_deg=np.degrees(t_rb), results=data)


# ---------------------------------------------------------------------------------------------- (b)
def part_b(motes, quick):
    etas = [1.0, 1.001, 1.01, 1.05, 1.1]
    radii = [1.0, 10.0, 100.0]
    rows, recs = [], []
    for r in radii:
        x = float(motes.size_parameter(r, C.LAM))
        area = np.pi * r * r
        for eta in etas:
            c_mie = float(motes.cross_sections(r, C.LAM, eta, method="mie")["ext"])
            with np.errstate(all="ignore"):
                c_ours = float(motes.goa_extinction_efficiency(x, eta)) * area
                c_paper = float(motes.goa_extinction_efficiency(x, eta, regularise=False, edge_correction=False)) * area
                c_ours_noedge = float(motes.goa_extinction_efficiency(x, eta, edge_correction=False)) * area
            c_cs = float(motes.cross_sections(r, C.LAM, eta, method="goa")["ext"])
            ratio = lambda c: (c / c_mie) if c_mie > 1e-12 * area else None  # noqa: E731
            recs.append(dict(r_um=r, x=x, eta=eta, c_mie=c_mie, c_ours=c_ours, c_ours_noedge=c_ours_noedge, c_paper=c_paper,
                             c_cross_sections=c_cs, ratio_ours=ratio(c_ours), ratio_ours_noedge=ratio(c_ours_noedge), ratio_paper=ratio(c_paper)))
            rows.append([r, C.eta_label(eta), c_mie, c_ours, c_paper, ratio(c_ours), ratio(c_paper), c_ours_noedge, ratio(c_ours_noedge)])
    C.print_table(
        "(b) eta → 1: C_ext (µm²) and C_ext(GOA)/C_ext(Mie); paper = Eq. 12 verbatim, unclamped (— : Mie C_ext = 0)",
        ["r (µm)", "eta", "C_ext Mie", "C_ext ours", "C_ext paper", "ours/Mie", "paper/Mie", "C_ext ours without edge term", "ours without edge / Mie"],
        rows,
    )
    return recs


# ---------------------------------------------------------------------------------------------- (c)
def part_c(motes, quick):
    th = np.array([0.0, 1e-6, np.pi - 1e-6, np.pi])
    rows, recs = [], []
    for eta in (1.33, 0.75, 1.5 + 0.01j):
        for r in (1.0, 10.0, 100.0):
            m1, m2 = motes.mie_amplitudes(r, C.LAM, eta, th)
            for reg in (True, False):
                g1, g2 = motes.goa_amplitudes(r, C.LAM, eta, th, regularise=reg)
                finite = bool(np.all(np.isfinite(g1)) and np.all(np.isfinite(g2)))
                cont0 = float(abs(g1[1] - g1[0]) / abs(g1[0]))
                contpi = float(abs(g1[3] - g1[2]) / max(abs(g1[3]), 1e-300))
                sym0 = float(abs(g1[0] - g2[0]) / abs(g1[0]))
                sympi = float(abs(g1[3] + g2[3]) / max(abs(g1[3]), 1e-300))
                err0 = float(abs(g1[0] - m1[0]) / abs(m1[0]))
                errpi = float(abs(g1[3] - m1[3]) / abs(m1[3]))
                recs.append(dict(eta=C.eta_label(eta), r_um=r, regularise=reg, finite=finite, S1_goa=g1, S2_goa=g2, S1_mie=m1, S2_mie=m2,
                                 cont0=cont0, contpi=contpi, sym0=sym0, sympi=sympi, err0_vs_mie=err0, errpi_vs_mie=errpi))
                rows.append([C.eta_label(eta), r, "ours" if reg else "paper", finite, abs(g1[0]), abs(m1[0]), cont0, sym0, err0,
                             abs(g1[3]), abs(m1[3]), contpi, sympi, errpi])
    C.print_table(
        "(c) θ → 0 and π: |S1| at 0 and π, continuity |S1(1e-6)−S1(0)|/|S1(0)| and |S1(π−1e-6)−S1(π)|/|S1(π)|, "
        "symmetry |S1(0)−S2(0)|/|S1(0)| and |S1(π)+S2(π)|/|S1(π)|, error |S1−S1_Mie|/|S1_Mie|",
        ["eta", "r (µm)", "GOA", "finite", "|S1(0)|", "|S1(0)| Mie", "cont. 0", "S1=S2 at 0", "err 0",
         "|S1(π)|", "|S1(π)| Mie", "cont. π", "S1=−S2 at π", "err π"],
        rows,
    )
    return recs


# ---------------------------------------------------------------------------------------------- (d)
def part_d(motes, quick):
    th = C.THETA
    deg = np.degrees(th)
    w = window(deg, 170, 180)
    rows, recs, curves = [], [], {}
    for eta in (1.33, 0.75, 1.5 + 0.01j):
        for r in (10.0, 100.0):
            M = C.amp_mean(*motes.mie_amplitudes(r, C.LAM, eta, th))
            rec = dict(eta=C.eta_label(eta), r_um=r, mie_max=float(M[w].max()))
            for reg in (True, False):
                G = C.amp_mean(*motes.goa_amplitudes(r, C.LAM, eta, th, regularise=reg))
                k = "ours" if reg else "paper"
                rec[f"relmse_{k}"] = C.relmse(G[w], M[w])
                rec[f"max_{k}"] = float(G[w].max())
                curves[(C.eta_label(eta), r, k)] = G[w]
            curves[(C.eta_label(eta), r, "mie")] = M[w]
            recs.append(rec)
            rows.append([rec["eta"], r, rec["relmse_ours"], rec["relmse_paper"], rec["mie_max"], rec["max_ours"], rec["max_paper"]])
    C.print_table(
        "(d) glory: (|S1|+|S2|)/2 in 170–180° (1800-angle grid, θ = π included)",
        ["eta", "r (µm)", "RelMSE ours", "RelMSE paper", "max Mie", "max ours", "max paper"],
        rows,
    )
    return dict(theta_window_deg=deg[w], results=recs, curves=curves)


# ---------------------------------------------------------------------------------------------- (e)
def edge_term_study(motes, quick: bool, out: pathlib.Path, plt) -> dict:
    """Edge term: C_ext error vs Mie with / without it, and the ripple-averaged coefficient c."""
    bands, chk = edge_bands(motes, quick)
    coefs, nx = edge_coefficients(motes, quick)
    plot_edge_term(motes, quick, out, plt, coefs)
    return dict(bands=bands, coefficients={str(k): v for k, v in coefs.items()}, x_range=[200, 400], n_x=nx,
                cross_sections_consistency_max_abs_dQ=chk)


def edge_bands(motes, quick: bool):
    """Print the (e) table of the C_ext error with / without the edge term per r band; return (bands, the
    largest |dQ| between ``cross_sections`` and ``goa_extinction_efficiency``)."""
    n_band = 400 if quick else 2000
    rows, bands = [], []
    for eta in (1.33, 1.5, 0.75):
        for lo, hi in ((10.0, 100.0), (100.0, 1000.0)):
            r = np.geomspace(lo, hi, n_band)
            x = np.asarray(motes.size_parameter(r, C.LAM))
            c_mie = motes.cross_sections(r, C.LAM, eta, method="mie")["ext"]
            area = np.pi * r**2
            # cross_sections(method="goa")["ext"] is exactly this (clamped at >= C_abs); it also integrates
            # sca and g over a grid with ~16 alpha nodes, far too slow for thousands of radii up to x ~ 1e4.
            c_e = motes.goa_extinction_efficiency(x, eta) * area
            c_n = motes.goa_extinction_efficiency(x, eta, edge_correction=False) * area
            e_e = (c_e - c_mie) / c_mie
            e_n = (c_n - c_mie) / c_mie
            rec = dict(eta=eta, r_lo=lo, r_hi=hi, n=n_band, mean_abs_with=float(np.mean(np.abs(e_e))), mean_abs_without=float(np.mean(np.abs(e_n))),
                       bias_with=float(np.mean(e_e)), bias_without=float(np.mean(e_n)))
            bands.append(rec)
            rows.append([eta, f"[{lo:g}, {hi:g}]", rec["mean_abs_without"], rec["mean_abs_with"], rec["bias_without"], rec["bias_with"]])
    # spot check that cross_sections gives the same ext
    r_chk = np.array([10.0, 31.6, 100.0])
    chk = float(np.max(np.abs(motes.cross_sections(r_chk, C.LAM, 1.33, method="goa")["ext"]
                              - motes.goa_extinction_efficiency(motes.size_parameter(r_chk, C.LAM), 1.33) * np.pi * r_chk**2)
                       / (np.pi * r_chk**2)))
    C.print_table(
        "(e) edge term: relative C_ext error (C_GOA − C_Mie)/C_Mie, regularised GOA p=3, mean over log-spaced radii in the band "
        "(the code leaves the term out for eta < 1)",
        ["eta", "r band (µm)", "mean |err| without edge", "mean |err| with edge", "mean err (bias) without", "mean err (bias) with"],
        rows,
    )
    return bands, chk


def edge_coefficients(motes, quick: bool):
    """Print the (e) table of the ripple-averaged coefficient c (Mie and GOA); return (c per eta, points in x)."""
    nx = 4000 if quick else 20000
    xs = np.linspace(200.0, 400.0, nx)
    r = C.radius_of_x(xs)
    coef_rows, coefs = [], {}
    for eta in (0.75, 1.33, 1.5):
        q = motes.cross_sections(r, C.LAM, eta, method="mie")["ext"] / (np.pi * r**2)
        y = (q - 2.0) * xs ** (2.0 / 3.0)
        c_mean = float(np.mean(y))
        c_lo = float(np.mean(y[xs < 300.0]))
        c_hi = float(np.mean(y[xs >= 300.0]))
        xs_far = np.linspace(1000.0, 2000.0, nx)  # does the ripple average stay constant at larger x?
        r_far = C.radius_of_x(xs_far)
        q_far = motes.cross_sections(r_far, C.LAM, eta, method="mie")["ext"] / (np.pi * r_far**2)
        c_far = float(np.mean((q_far - 2.0) * xs_far ** (2.0 / 3.0)))
        qg_e = motes.goa_extinction_efficiency(xs, eta)
        qg_n = motes.goa_extinction_efficiency(xs, eta, edge_correction=False)
        cg_e = float(np.mean((qg_e - 2.0) * xs ** (2.0 / 3.0)))
        cg_n = float(np.mean((qg_n - 2.0) * xs ** (2.0 / 3.0)))
        coefs[eta] = dict(c_mean=c_mean, c_200_300=c_lo, c_300_400=c_hi, c_1000_2000=c_far, goa_with_edge=cg_e, goa_without_edge=cg_n,
                          ripple_std=float(np.std(y)))
        coef_rows.append([eta, c_mean, c_lo, c_hi, c_far, cg_e, cg_n])
    C.print_table(
        f"(e) ripple-averaged edge coefficient c in Q_ext ≈ 2 + c·x^(−2/3) from Mie, x ∈ [200, 400] ({nx} points); "
        f"Nussenzveig–Wiscombe (η > 1): c = {NW_C} (with −0.7153537 x^(−4/3))",
        ["eta", "c = mean((Q−2)·x^(2/3)), Mie", "same, x ∈ [200, 300)", "same, x ∈ [300, 400]", "same, x ∈ [1000, 2000]", "same mean, GOA with edge", "same mean, GOA without edge"],
        coef_rows,
    )
    return coefs, nx


def plot_edge_term(motes, quick: bool, out: pathlib.Path, plt, coefs: dict) -> None:
    """``edge_term.png``: (Q - 2) x^(2/3) against x, Mie and GOA with / without the edge term."""
    xs_p = np.geomspace(20.0, 3000.0, 1500 if quick else 6000)
    rp = C.radius_of_x(xs_p)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4))
    for ax, eta in zip(axes, (1.33, 1.5, 0.75)):
        q = motes.cross_sections(rp, C.LAM, eta, method="mie")["ext"] / (np.pi * rp**2)
        y = (q - 2.0) * xs_p ** (2.0 / 3.0)
        k = 101
        ys = np.convolve(y, np.ones(k) / k, mode="same")
        ax.semilogx(xs_p, y, color="tab:blue", lw=0.3, alpha=0.5, label="Mie")
        ax.semilogx(xs_p[k:-k], ys[k:-k], color="tab:blue", lw=1.2, label=f"Mie, running mean ({k} pts)")
        for ed, col in ((True, "tab:red"), (False, "k")):
            qg = motes.goa_extinction_efficiency(xs_p, eta, edge_correction=ed)
            yg = (qg - 2.0) * xs_p ** (2.0 / 3.0)
            ax.semilogx(xs_p, yg, color=col, lw=0.6, alpha=0.7, label=f"GOA p=3 {'with' if ed else 'without'} edge term")
        ax.axhline(NW_C, color="0.4", ls="--", lw=0.8, label=f"N–W c = {NW_C:.3f}")
        ax.axhline(coefs.get(eta, {}).get("c_mean", np.nan), color="tab:green", ls=":", lw=1.0, label="measured c (x ∈ [200, 400])")
        ax.axvspan(200, 400, color="tab:green", alpha=0.08)
        ax.set_ylim(-6, 8)
        ax.set_xlabel("x")
        ax.set_ylabel("(Q_ext − 2)·x^(2/3)")
        ax.set_title(f"edge term, η = {eta}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    C.save_fig(fig, out / "edge_term.png")


# ---------------------------------------------------------------------------------------------- main
def plot_main(out, plt, a, b, d):
    fig, axes = plt.subplots(2, 2, figsize=(14, 8.5))
    # (a)
    ax = axes[0, 0]
    for r, ls in ((10.0, "-"), (100.0, "-")):
        cv = a["results"][r]["curves"]
        off = 0 if r == 10.0 else 2
        ax.semilogy(a["theta_window_deg"], cv["mie"] * 10**off, color="tab:blue", lw=0.8, label="Mie" if r == 10 else None)
        ax.semilogy(a["theta_window_deg"], cv["ours"] * 10**off, color="tab:red", lw=0.8, label="GOA ours" if r == 10 else None)
        ax.semilogy(a["theta_window_deg"], cv["paper"] * 10**off, color="k", lw=0.7, ls="--", label="GOA paper" if r == 10 else None)
        ax.text(126, cv["mie"][0] * 10**off * 2, f"r = {r:g} µm (×{10**off:g})", fontsize=8)
    ax.axvline(a["rainbow_deg"], color="0.5", ls=":", lw=0.8)
    C.label(ax, "θ (deg)", "|S1|", "(a) primary rainbow, η = 1.33", legend=8)
    # (b)
    ax = axes[0, 1]
    etas = sorted({rec["eta"] for rec in b})
    for i, r in enumerate((1.0, 10.0, 100.0)):
        sel = [rec for rec in b if rec["r_um"] == r and rec["ratio_ours"] is not None]
        ax.semilogx([s["eta"] - 1 for s in sel], [s["ratio_ours"] for s in sel], "o-", color=f"C{i}", label=f"ours, r = {r:g} µm")
        ax.semilogx([s["eta"] - 1 for s in sel], [s["ratio_paper"] for s in sel], "x--", color=f"C{i}", label=f"paper, r = {r:g} µm")
    ax.axhline(1.0, color="0.5", lw=0.6)
    ax.set_ylim(-3, 5)
    ax.set_xlabel("η − 1")
    ax.set_ylabel("C_ext(GOA) / C_ext(Mie)")
    ax.set_title(f"(b) η → 1 (η = {', '.join(f'{e:g}' for e in etas)}; η = 1: Mie C_ext = 0)")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(True, which="both", alpha=0.3)
    # (d)
    for ax, eta in ((axes[1, 0], "1.33"), (axes[1, 1], "0.75")):
        for r, off in ((10.0, 0), (100.0, 2)):
            cv = d["curves"]
            ax.semilogy(d["theta_window_deg"], cv[(eta, r, "mie")] * 10**off, color="tab:blue", lw=0.8, label="Mie" if r == 10 else None)
            ax.semilogy(d["theta_window_deg"], cv[(eta, r, "ours")] * 10**off, color="tab:red", lw=0.8, label="GOA ours" if r == 10 else None)
            ax.semilogy(d["theta_window_deg"], cv[(eta, r, "paper")] * 10**off, color="k", lw=0.7, ls="--", label="GOA paper" if r == 10 else None)
        C.label(ax, "θ (deg)", "(|S1|+|S2|)/2 (r = 100 µm ×100)", f"(d) backward / glory window, η = {eta}, r = 10 and 100 µm", legend=8)
    C.save_fig(fig, out / "singularities.png")


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    plt = C.plt()
    a = part_a(motes, args.quick)
    b = part_b(motes, args.quick)
    c = part_c(motes, args.quick)
    d = part_d(motes, args.quick)
    e = edge_term_study(motes, args.quick, out, plt)
    plot_main(out, plt, a, b, d)
    a_json = dict(rainbow_deg=a["rainbow_deg"], results={str(r): {k: v for k, v in rec.items() if k != "curves"} for r, rec in a["results"].items()})
    C.finish(args, sw, out / "singularities.json", wavelength_um=C.LAM, a_rainbow=a_json, b_eta_to_1=b, c_axis=c, d_glory=d["results"],
             e_edge=e)


if __name__ == "__main__":
    main()
