"""Write docs/gallery.md from the sheets and numbers the figure scripts left in docs/gallery/ (each
script writes NAME.png and NAME.json): every number on the page is read from those JSON files, so the
page says what the last run measured. Run after the scripts (``scripts/paper/run_all.sh`` does both).

    .venv/bin/python scripts/paper/gallery_md.py [--gallery docs/gallery] [--out docs/gallery.md]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]


def load(folder: pathlib.Path, name: str):
    p = folder / f"{name}.json"
    return json.loads(p.read_text()) if p.exists() else None


def pm(m, se, digits=4):
    return f"{m:.{digits}g} ± {se:.2g}"


def verdict(ok) -> str:
    return "**holds**" if ok else "**does not hold**"


def table(*columns: str) -> list[str]:
    """A Markdown table's head: the column titles and the line under them."""
    return ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def quality(d) -> str:
    return f"{d['res']}×{d['res']} px, {d['spp']} spp, `{d['variant']}`"


def fig10(d):
    lines = table("PSD (r_g, σ_g)", "motes, beam mean", "EPT, beam mean", "EPT / motes", "render s (motes, EPT)")
    for r in d["rows"]:
        ept = r.get("ept_mean")
        lines.append(f"| {r['radius_median']} µm, {r['sigma_g']} | {pm(r['motes_mean'], r['motes_se'])} | "
                     + (f"{pm(ept, r['ept_se'])} | {ept / r['motes_mean']:.3f} | {r['motes_render_s']:.1f}, "
                        f"{r['ept_render_s']:.1f} |" if ept is not None else "– | – | – |"))
    lines.append(f"\nEPT darker than motes for the smallest grains (beyond 2 SE): {verdict(d['ept_darker_for_small_grains'])}.")
    return lines


def fig12(d):
    im = d["images"]
    lines = table("image", "mean ± SE", "render s")
    for k, v in im.items():
        lines.append(f"| {k} | {pm(v['mean'], v['se'])} | {v['render_s']:.1f} |")
    lines += [""] + table("pair", "relative difference of means", "RMS(difference) / noise")
    for k, v in d["pairs"].items():
        lines.append(f"| {k} | {v['rel_diff']:+.4f} ± {v['rel_diff_se']:.4f} | {v['rms_over_noise']:.2f} |")
    lines.append(f"\nThe grains' asymmetry g at 532 nm: {d['phase']['g']:.4f} (the HG of Fig. 13 has the same g).")
    return lines


def fig14(d):
    lines = table("N", "radius", "storage", "mean D / H − 1", "RMS(D − H) / noise", "transmittance D / H",
                  "medium graininess", "render s")
    for r in d["rows"]:
        lines.append(f"| {r['count']:.0e} | {r['radius_um']:.1f} µm | {r['storage']} | {r['rel_diff']:+.4f} ± "
                     f"{r['rel_diff_se']:.4f} | {r['rms_over_noise']:.2f} | {r['transmittance_ratio']:.4f} ± "
                     f"{r['transmittance_ratio_se']:.4f} | {r['graininess']:.3f} | {r['render_s']:.1f} |")
    lines.append(f"\nRMS(D − H)/noise falls to the noise floor: {verdict(d['rms_falls'])}; graininess falls with N: "
                 f"{verdict(d['graininess_falls'])}; the largest N matches `homogeneous`: {verdict(d['converged'])} (by "
                 "construction: at the largest N every size class is continuous, so that image is the continuous "
                 "medium's; the convergence shows in the rows before it).")
    return lines


def fig16(d):
    lines = table("N", "k", "mean ± SE", "MC noise per pixel / mean", "medium graininess", "render s")
    for res in d["results"]:
        for r in res["rows"]:
            lines.append(f"| {r['count']:.0e} | {r['k']:g} | {pm(r['mean'], r['se'])} | {r['mc_noise']:.2f} | "
                         f"{r['graininess']:.3f} | {r['render_s']:.1f} |")
    for res in d["results"]:
        lines.append(f"\nN = {res['count']:.0e}: brightness independent of k (3 SE or 3 %): "
                     f"{verdict(res['same_brightness'])}; graininess falls as k grows: {verdict(res['graininess_falls'])}.")
    return lines


def fig17(d):
    lines = table("particles per cell", "cells", "render s", "load s")
    for r in d["rows"]:
        lines.append(f"| {r['particles_per_cell']:.3g} | {r['cells']:.0f} (~{r['cells_per_axis_cubic']:.0f}³) | "
                     f"{r['render_s']:.2f} | {r['load_s']:.2f} |")
    lines.append(f"\nFastest at {d['fastest_particles_per_cell']:.3g} particles per cell; one per cell (the paper's "
                 f"optimum) takes {d['one_per_cell_over_fastest']:.2f}× the fastest.")
    return lines


def fig18(d):
    lines = table("η_i", "image mean ± SE", "render s")
    for r in d["rows"]:
        lines.append(f"| {r['eta_k']:g} | {pm(r['mean'], r['se'])} | {r['render_s']:.1f} |")
    lines.append(f"\nScattering dims at every step of η_i (beyond 2 SE): {verdict(d['dims_monotonically'])}.")
    return lines


def fig19(d):
    lines = table("row", "PSD", "sky mean ± SE", "mean optical depth", "medium graininess", "render s")
    for key, label in (("r_g", "r_g"), ("sigma_g", "σ_g"), ("bimodal", "bimodal")):
        for r in d[key]:
            psd = (f"r_g {r['radius_median']} µm, σ_g {r['sigma_g']}" if key != "bimodal" else
                   f"2e7: r_g1 {r['radius_median']} µm (σ_g 1) + 1e5 of {r['radius2']} µm")
            lines.append(f"| {label} | {psd} | {pm(r['mean'], r['se'])} | {r['tau']:.3g} | {r['graininess']:.3f} | "
                         f"{r['render_s']:.1f} |")
    lines.append(f"\nScattering grows with r_g (beyond 2 SE at every step): {verdict(d['brighter_with_r_g'])}; "
                 f"graininess grows with σ_g: {verdict(d['grainier_with_sigma_g'])}.")
    return lines


def sky(d):
    lines = table("grains", "DoLP, 99th percentile", "there, angle from the sun", "single scattering's −F12/F11 there",
                  "render s")
    for r in d["rows"]:
        lines.append(f"| {r['label']} | {r['dolp_p99']:.3f} | {r['angle_of_max_deg']:.1f}° | "
                     f"{r['single_scattering_dolp_there']:+.3f} | {r['render_s']:.1f} |")
    lines.append(f"\nThe smallest grains polarise most 90 ± 10° from the sun: {verdict(d['max_at_90_deg'])}.")
    return lines


#: What the numbers mean, per figure (no numbers here: those come from the JSON files).
NOTES = {
    "fig10_lamp": "EPT finds light only when a chain of refractions and reflections through the spheres' delta "
                  "BSDFs happens to hit the lamp's disk (no next-event estimation is possible), so its estimate "
                  "is heavy-tailed: at low spp its mean falls below its expectation and its SE is larger; both "
                  "renderers run at max_depth 32, since EPT spends two or more bounces on each grain.",
    "fig12_13_cornell": "FD is darker than -FD because every diffraction event (a few tenths of a mrad) counts "
                        "as a scattering event: the events per path double and max_depth 12 cuts paths earlier. "
                        "EPT spends two or more bounces per grain and loses a little more to the same limit. The "
                        "default truncation (the pixel footprint) is close to -FD, as the paper's point predicts.",
    "fig14_limit": "At the sparsest counts the discrete image mean sits about a per cent below the homogeneous "
                   "one, beyond its SE, while the mean transmittance along the camera's pixel cylinders agrees "
                   "with the homogeneous medium's within its SE: the extinction is right, so the difference is in "
                   "what the grains scatter towards the camera (not yet explained; candidates: scattering "
                   "events spread over disks widened by tau_max, grains whose disks cross the cube's faces where "
                   "the medium ends).",
    "fig16_footprint": "",
    "fig17_bench": "motes's optimum lies at several grains per cell rather than one: its cells hold blocks of "
                   "eight spheres tested together (SIMD), so a cell of a few grains costs about what a cell of one "
                   "does, and fewer cells mean fewer DDA steps: the curve is nearly flat over several grains per cell and "
                   "rises as cells get finer than two grains each.",
    "fig18_staircase": "Beyond eta_i ~ 1e-3 (absorption length 44 um against 0.8 mm grains) the grains are opaque "
                       "and more absorption changes only their surface reflection, so the sweep stops there.",
    "sky_polarisation": "Multiple scattering (max_depth 4) adds unpolarised light, so the rendered DoLP stays "
                        "below single scattering's where that is large; where the sky is dim (the droplets' far "
                        "side) Monte Carlo noise in S1 and S2 inflates the 99th percentile.",
    "fig19_house": "Beyond sigma_g ~ 2.4 the extinction-weighted radii reach the paper's cap r_max = 2 mm, which "
                   "narrows them again, and the graininess stops growing; the sweep stops there. The bimodal rows' "
                   "haze (the small mode, mostly continuous) lowers the graininess of the sky at equal mean.",
}

SECTIONS = [
    ("fig10_lamp", "LAMP — Fig. 10: PSDs, EPT against motes", "lamp",
     "“Since only surface reflection and refraction are computed for EPT, the energy inherently belonging to the "
     "Fraunhofer diffraction is not correctly captured … resulting in overly sparse and specular volumetric glints”; "
     "“EPT easily misses many small particles”.", fig10),
    ("fig12_13_cornell", "CORNELL — Figs. 12–13: diffraction, EPT, Henyey–Greenstein", "cornell",
     "At 1000 µm “pure geometric optics becomes applicable”: without Fraunhofer diffraction the grains look like the "
     "full model, with “subtle differences”; the best-fit HG “cannot faithfully encode the scattering pattern”, so "
     "the rendering is “slightly different”.", fig12),
    ("fig14_limit", "LIMIT — Figs. 14–15: the continuous limit", "limit",
     "“As N_tot increases, the appearance tends to become hazy, and the rendering result gets closer to the "
     "corresponding continuous medium”; at 10^8 it “produces smooth appearance matching that from a continuous medium”.",
     fig14),
    ("fig16_footprint", "FOOTPRINT — Fig. 16: the query radius", "footprint",
     "k in [0.5, 1] gives a faithful grainy look; a too large k keeps “the overall brightness” but the glints are "
     "“overly blurred”; a too small k “will miss many particles … inefficient, especially when the medium is very "
     "sparse”, while k = 0.2 looks like k = 0.5 in a denser medium.", fig16),
    ("fig17_bench", "BENCH — Fig. 17: grid resolution", "bench",
     "“a grid resolution yielding roughly one particle per voxel achieves the optimum solution for most scenes” "
     "(60³ for 2·10^5 grains).", fig17),
    ("fig18_staircase", "STAIRCASE — Fig. 18: absorbing dust", "staircase",
     "“An increase of η_i will increasingly dim the intensity of scattering.”", fig18),
    ("fig19_house", "HOUSE — Fig. 19: the PSD of blowing snow", "house",
     "“The scattering effects become increasingly prominent as r_g grows”; σ_g “is responsible for the level of "
     "graininess”; a bimodal cloud shows “both haziness from massive small particles and graininess from a handful "
     "of large particles”.", fig19),
    ("sky_polarisation", "SKY — polarisation (beyond the paper's figures)", None,
     "a framework “considering diffraction, polarization, a wide range of PSDs”, with amplitudes S1 and S2 for "
     "“perpendicular and parallel polarizations” (Sec. 3), though it shows no polarised image. Here: sunlit grains "
     "overhead in `llvm_ad_spectral_polarized` with Mitsuba's `stokes` integrator.", sky),
]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gallery", default=str(ROOT / "docs" / "gallery"))
    ap.add_argument("--out", default=str(ROOT / "docs" / "gallery.md"))
    args = ap.parse_args()
    folder, out = pathlib.Path(args.gallery), pathlib.Path(args.out)
    rel = folder.relative_to(out.parent) if folder.is_relative_to(out.parent) else folder
    md = ["# Gallery: the paper's experiments (Guo et al., Sec. 6) re-run with motes", "",
          "Each scene ships with motes (`motes scenes` lists them, `motes render NAME` renders one at its defaults; the",
          "header of each XML says what it shows and which parameters it takes). Each sheet below is rendered by a script",
          "in `scripts/paper/` at preview quality (minutes on 2 cores; `--full` for the paper's quality), and each claim",
          "the paper makes about the figure is checked by a number that script measured. This page is written by",
          "`scripts/paper/gallery_md.py` from the scripts' JSON output: `bash scripts/paper/run_all.sh` re-renders",
          "everything and rewrites it.", "",
          "Conventions: image means are luminance means with their Monte Carlo standard error from two renders with",
          "different sampler seeds on the same grains; “RMS / noise” is the RMS over pixels of a difference image divided",
          "by its Monte Carlo noise floor (1: the two images agree to their noise); the *medium graininess* is",
          "std / mean over pixels of the optical depth per unit length along each pixel's query cylinder (Eq. 18, as the",
          "renderer's free flights see it: exact, no Monte Carlo noise), i.e. the grains' texture at equal mean.", ""]
    table1 = load(folder, "table1")
    for name, title, scene, claim, fmt in SECTIONS:
        d = load(folder, name)
        md += [f"## {title}", "", f"![{title}]({rel}/{name}.png)", ""]
        if name == "fig12_13_cornell" and (folder / "fig13_phase.png").exists():
            md += [f"![The grains' phase function and the Henyey–Greenstein of the same g]({rel}/fig13_phase.png)", ""]
        where = f"Scene `{scene}` (`motes render {scene}`); script" if scene else "Script"
        md += [f"{where} `.venv/bin/python scripts/paper/{name}.py`.", "", f"The paper: {claim}", ""]
        if d is None:
            md += ["(not rendered yet)", ""]
            continue
        md += [f"Measured ({quality(d)}):", ""] + fmt(d) + [""]
        if NOTES.get(name):
            md += [NOTES[name], ""]
    if table1 is not None:
        md += ["## Table 1 re-measured", "", "See `BENCHMARKS.md`, section \"The gallery and the paper's Table 1\", for the table with its command "
               "(`scripts/paper/table1.py`).", ""]
    out.write_text("\n".join(md) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
