"""Forward-peak truncation (issue 3): what it saves and what it changes, in a numerical experiment.

A collimated beam enters a slab of the paper's ice cloud (log-normal r_g = 800 µm, sigma_g = 4, eta 1.31,
lambda 0.55 µm) of optical thickness tau; photons are traced by Monte Carlo (vectorised numpy, analog
absorption) with the ensemble phase function, once with the full properties and once with the forward peak
narrower than theta_c folded into unscattered transmission (``truncate_below_rad``). Reported: scattering
events per photon path, transmitted and reflected energy, and the L1 difference of the exit-angle
distributions at a "pixel" resolution of 2 theta_c (what an image with that angular pixel size sees).

    .venv/bin/python scripts/figures/truncation_experiment.py [--quick] [--out out]
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # scripts/, which holds _common.py
import numpy as np  # noqa: E402

import _common as C  # noqa: E402


def trace(sigma_t: float, albedo: float, table, thickness: float, n: int, seed: int):
    """Photons start at z = 0 moving +z; returns (transmitted exit cos, reflected count, events, absorbed)."""
    rng = np.random.default_rng(seed)
    pos = np.zeros(n)
    d = np.zeros((n, 3))
    d[:, 2] = 1.0
    events = np.zeros(n, dtype=np.int64)
    alive = np.ones(n, dtype=bool)
    t_mu = []
    reflected = absorbed = 0
    while alive.any():
        idx = np.flatnonzero(alive)
        s = -np.log1p(-rng.random(idx.size)) / sigma_t
        z = pos[idx] + s * d[idx, 2]
        out_t = z >= thickness
        out_r = z < 0
        t_mu.append(d[idx[out_t], 2])
        reflected += int(out_r.sum())
        alive[idx[out_t | out_r]] = False
        inside = idx[~(out_t | out_r)]
        pos[inside] = z[~(out_t | out_r)]
        # interaction: absorb with probability 1 - albedo, else scatter
        absorb = rng.random(inside.size) >= albedo
        absorbed += int(absorb.sum())
        alive[inside[absorb]] = False
        sc = inside[~absorb]
        events[sc] += 1
        theta = table.sample(rng.random(sc.size))
        phi = 2 * np.pi * rng.random(sc.size)
        d[sc] = rotate(d[sc], theta, phi)
    return np.concatenate(t_mu), reflected, events, absorbed


def rotate(d: np.ndarray, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Directions d turned by polar angle theta and azimuth phi about themselves (pbrt's frame)."""
    ct, st = np.cos(theta), np.sin(theta)
    cp, sp = np.cos(phi), np.sin(phi)
    # orthonormal frame around d
    a = np.where(np.abs(d[:, 2:3]) < 0.999, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    u = np.cross(a, d)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    out = st[:, None] * (cp[:, None] * u + sp[:, None] * v) + ct[:, None] * d
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def main() -> None:
    args, out, sw, motes = C.start(__doc__)
    n = 40_000 if args.quick else 400_000
    tau = 2.0
    ice = motes.Species(motes.LogNormal(800.0, 4.0), 1.31 + 1e-9j)
    full = motes.bulk_properties(ice, 1e4, 0.55)
    thickness = tau / full["sigma_t"][0]
    rows = []
    hist = {}
    for theta_c in (None, 1e-4, 1e-3, 3e-3, 1e-2):
        b = full if theta_c is None else motes.bulk_properties(ice, 1e4, 0.55, truncate_below_rad=theta_c)
        table = motes.PhaseTable.from_bulk(b)
        mu_t, n_r, events, n_abs = trace(b["sigma_t"][0], b["albedo"][0], table, thickness, n, seed=3)
        hist[theta_c] = mu_t
        rows.append([theta_c if theta_c is not None else 0.0, b["peak_fraction"][0], b["sigma_t"][0] * thickness, events.mean(),
                     mu_t.size / n, n_r / n, n_abs / n])
    base_events = rows[0][3]
    for r in rows:
        r.insert(4, 1 - r[3] / base_events)
    # image proxy: exit-angle distribution of transmitted light at pixel size 2 theta_c
    diffs = []
    for theta_c in (1e-4, 1e-3, 3e-3, 1e-2):
        px = 2 * theta_c
        edges = np.concatenate([np.arange(0, 0.2, px), [np.pi / 2]])
        h0, _ = np.histogram(np.arccos(np.clip(hist[None], -1, 1)), edges)
        h1, _ = np.histogram(np.arccos(np.clip(hist[theta_c], -1, 1)), edges)
        se = np.sqrt(h0 + h1).sum() / n
        diffs.append([theta_c, px, np.abs(h1 - h0).sum() / n, se])
    C.print_table(f"Slab of the paper's ice cloud, tau = {tau} (untruncated), {n:g} photons, collimated beam",
                  ["theta_c (rad)", "peak fraction F", "tau after truncation", "scattering events / path", "events saved",
                   "transmitted", "reflected", "absorbed"], rows)
    C.print_table("Exit-angle distribution of transmitted light at pixel size 2 theta_c: L1 difference (fraction of photons) and its noise scale",
                  ["theta_c (rad)", "pixel (rad)", "L1 difference", "MC noise scale (sum of sqrt counts / N)"], diffs)
    C.finish(args, sw, out / "truncation_experiment.json", rows=rows, diffs=diffs)


if __name__ == "__main__":
    main()
