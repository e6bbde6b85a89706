"""Gallery: the degree of polarisation of sunlight scattered by grains overhead (issue 45).

A camera on the ground looks straight up (120 deg field of view) into a 20-unit-thick layer of grains lit by
the sun at 35 deg elevation (a directional light; no other light), in `llvm_ad_spectral_polarized` with
Mitsuba's `stokes` integrator around `volpath` (max_depth 4: multiple scattering, which depolarises). Three
clouds of the same optical depth (0.3 vertically): air-like molecules' size (0.05 um, glass), haze
(0.5 um, glass), cloud droplets (5 um, water). Top row: the sky's radiance (S0); bottom row: its degree of
linear polarisation sqrt(S1^2 + S2^2) / S0.

The check: the brightest-polarised sky of the smallest grains lies 90 deg from the sun, where Rayleigh
scattering polarises fully (measured: the angle of the 99th percentile of DoLP, against 90 +- 10 deg), and
the DoLP there approaches single scattering's -F12/F11 (`motes.mueller_matrix`) less what multiple
scattering adds unpolarised. Writes docs/gallery/sky_polarisation.png and .json.

    .venv/bin/python scripts/paper/sky_polarisation.py [--full] [--spp N] [--res N]

Preview (32 spp, 96 px): about a minute on 2 cores; --full: 256 spp, 256 px.
"""

from __future__ import annotations

import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _paper as P  # noqa: E402

VARIANT = "llvm_ad_spectral_polarized"
SUN_ELEVATION_DEG = 35.0
#: (label, radius um, refractive index)
CLOUDS = (("molecule-sized grains, 0.05 um", 0.05, 1.5), ("haze, 0.5 um", 0.5, 1.5),
          ("cloud droplets, 5 um", 5.0, 1.33))
TAU = 0.3
SIGMA_G = 1.2
FOV = 120.0
# Channels of the Stokes render (RGB film): R, G, B, then S0..S3 as R, G, B each.
S0, S1, S2 = slice(3, 6), slice(6, 9), slice(9, 12)


def sun_travel() -> np.ndarray:
    """The direction sunlight travels (down, towards -x: the sun is on the image's right)."""
    e = np.radians(SUN_ELEVATION_DEG)
    return np.array([-np.cos(e), -np.sin(e), 0.0])


def scene_dict(mi, radius_um: float, eta: float, res: int, spp: int) -> dict:
    thickness = 20.0
    grains = {"type": "discrete", "sigma_t": TAU / thickness, "eta": eta, "scale_m": 1e-3, "storage": "procedural",
              "psd": json.dumps({"type": "lognormal", "median_um": radius_um, "sigma_g": SIGMA_G}),
              "phase": {"type": "particle"}}
    return {
        "type": "scene",
        "integrator": {"type": "stokes", "integrator": {"type": "volpath", "max_depth": 4}},
        "sensor": {"type": "perspective", "fov": FOV,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[0, 1, 0], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sun": {"type": "directional", "direction": sun_travel().tolist(), "irradiance": 1.0},
        "layer": {"type": "cube", "bsdf": {"type": "null"}, "interior": grains,
                  "to_world": mi.ScalarTransform4f().translate([0, 5 + thickness / 2, 0])
                  @ mi.ScalarTransform4f().scale([400, thickness / 2, 400])},
    }


def scattering_angles(mi, scene, res: int) -> np.ndarray:
    """Per pixel, the angle (deg) between the sunlight and the light reaching the camera along the pixel's ray."""
    sensor = scene.sensors()[0]
    u = (np.arange(res) + 0.5) / res
    x, y = np.meshgrid(u, u)
    rays, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(x.ravel(), y.ravel()), mi.Point2f(0.5, 0.5))
    d = np.stack([np.asarray(rays.d.x), np.asarray(rays.d.y), np.asarray(rays.d.z)], axis=1)
    cos = np.clip(-(d @ sun_travel()), -1.0, 1.0)
    return np.degrees(np.arccos(cos)).reshape(res, res)


def main() -> int:
    args = P.parser(__doc__, spp=32, res=96, full_spp=256, full_res=256).parse_args()
    spp, res = P.quality(args)
    mi = P.setup(VARIANT)
    import motes  # noqa: PLC0415

    panels, rows = [], []
    for label, r_um, eta in CLOUDS:
        scene = mi.load_dict(scene_dict(mi, r_um, eta, res, spp))
        t = time.perf_counter()
        img = np.asarray(mi.render(scene, spp=spp), dtype=np.float64)
        seconds = time.perf_counter() - t
        s0, s1, s2 = (img[..., k].mean(axis=-1) for k in (S0, S1, S2))
        dolp = np.hypot(s1, s2) / np.maximum(s0, 1e-12)
        angle = scattering_angles(mi, scene, res)
        top = dolp >= np.quantile(dolp, 0.99)
        theta_max = float(np.median(angle[top]))
        # The cloud's own single scattering there (its PSD's ensemble, Eq. 17): P = -F12/F11.
        ens = motes.bulk_properties(motes.Species(motes.LogNormal(r_um, SIGMA_G), eta), 1.0, [0.55],
                                    theta=np.radians([theta_max]), mueller=True)
        rows.append({"label": label, "radius_um": r_um, "eta": eta, "dolp_p99": float(np.quantile(dolp, 0.99)),
                     "angle_of_max_deg": theta_max,
                     "single_scattering_dolp_there": float(-ens["mueller"][0, 0, 0]),
                     "render_s": seconds})
        print(f"{label:34s} DoLP p99 {rows[-1]['dolp_p99']:.3f} at {theta_max:5.1f} deg from the sun "
              f"(single scattering there {rows[-1]['single_scattering_dolp_there']:+.3f}), {seconds:.1f} s", flush=True)
        panels.append((label, img[..., S0], dolp))
    ok = abs(rows[0]["angle_of_max_deg"] - 90.0) <= 10.0
    print(f"smallest grains polarise most at 90 +- 10 deg from the sun: {'PASS' if ok else 'FAIL'}")
    out = pathlib.Path(args.out)
    _figure(panels, out / "sky_polarisation.png", spp)
    P.save_numbers(out, "sky_polarisation", {"spp": spp, "res": res, "variant": VARIANT, "tau": TAU,
                                             "sun_elevation_deg": SUN_ELEVATION_DEG, "rows": rows,
                                             "max_at_90_deg": ok})
    return 0 if ok else 1


def _figure(panels, path: pathlib.Path, spp: int) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(2, len(panels), figsize=(3.0 * len(panels) + 0.8, 6.6), squeeze=False,
                             layout="constrained")
    for j, (label, s0, dolp) in enumerate(panels):
        axes[0][j].imshow(P._display(s0, *P.exposure_of(s0)), interpolation="nearest")
        im = axes[1][j].imshow(dolp, vmin=0.0, vmax=1.0, cmap="magma", interpolation="nearest")
        axes[0][j].set_title(label, fontsize=9)
        for ax in (axes[0][j], axes[1][j]):
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0][0].set_ylabel("radiance S0 (each its own exposure)", fontsize=9)
    axes[1][0].set_ylabel("degree of linear polarisation", fontsize=9)
    fig.colorbar(im, ax=axes[1].tolist(), shrink=0.9, label="DoLP")
    fig.suptitle(f"Looking straight up, sun {SUN_ELEVATION_DEG:g} deg above the horizon on the right: "
                 f"polarisation by grains\n(tau 0.3, {VARIANT}, {spp} spp; Rayleigh's band of full polarisation "
                 "90 deg from the sun, the droplets' bow)", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
