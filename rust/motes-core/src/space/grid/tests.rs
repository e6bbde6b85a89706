use super::*;

use crate::test_rng::{assert_escape_rate, lcg, random_direction, random_particles, random_points};
use std::f64::consts::PI;

/// Free flights interact at a particle with exactly the probability the transmittance implies:
/// P(no interaction on [t0, t1)) = exp(−τ) (binomial 5σ bound), and the interaction point has an
/// accumulated optical depth straddling −ln(1 − u).
#[test]
fn free_flight_matches_transmittance() {
    let mut s = 11u64;
    let (pos, rad) = random_particles(&mut s, 2000, 0.005, 0.01);
    let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r * 15.0).collect();
    let g = ParticleGrid::build(&pos, &rad, &cext, 1, &GridSettings::new(0.03, 1.0)).unwrap();
    assert!(g.class_count() >= 1);
    let ray = RaySegment::new([0.5, 0.5, -0.5], [0.0, 0.6, 0.8], 0.0, 3.0);
    let mut tau = [0.0];
    g.optical_depth(&ray, &mut tau);
    let expected = (-tau[0]).exp();
    assert!(tau[0] > 0.3 && tau[0] < 3.0, "{}", tau[0]);
    assert_escape_rate(&mut s, 20000, expected, |u| {
        let (hit, tr) = g.free_flight(&ray, 0, u);
        match hit {
            None => {
                assert!((tr - expected).abs() < 1e-12);
                true
            }
            Some(h) => {
                // accumulated depth before the hit ≤ target < accumulated + τ_hit
                let before = -tr.ln();
                let target = -(1.0 - u).ln();
                assert!(
                    before <= target + 1e-9 && target < before + g.tau_of(h.particle, 0) + 1e-9
                );
                false
            }
        }
    });
}

/// The segments `grid_equals_brute_force` queries: random ones (whole and in part), rays along
/// each axis from outside, rays on a cell face of the grid (`lo0 + 3 cell` in x) starting inside,
/// a zero-length segment and a ray missing the grid.
fn test_rays(s: &mut u64, lo0: f64, cell: f64) -> Vec<RaySegment> {
    let mut rays = Vec::new();
    for _ in 0..300 {
        let o = [lcg(s) * 3.0 - 1.0, lcg(s) * 3.0 - 1.0, lcg(s) * 3.0 - 1.0];
        let ray = RaySegment::new(o, random_direction(s), 0.0, 4.0);
        rays.push(ray);
        rays.push(ray.between(lcg(s), lcg(s) + 1.0));
    }
    for a in 0..3 {
        for sign in [1.0, -1.0] {
            let mut d = [0.0; 3];
            d[a] = sign;
            let mut o = [0.5, 0.5, 0.5];
            o[a] -= sign * 2.0;
            rays.push(RaySegment::new(o, d, 0.0, 5.0));
            // on a cell face of the grid and starting inside
            let mut o2 = [lo0 + 3.0 * cell, 0.37, 0.61];
            o2[a] = 0.5;
            rays.push(RaySegment::new(o2, d, 0.0, 3.0));
        }
    }
    let x = [1.0, 0.0, 0.0];
    rays.push(RaySegment::new([0.5, 0.5, 0.5], x, 0.3, 0.3)); // zero length
    rays.push(RaySegment::new([5.0, 5.0, 5.0], x, 0.0, 10.0)); // misses
    rays
}

/// The walk, the optical depth and the occupied interval of `ray` equal the O(N) loops: the walk
/// merges the classes' traversals, every contributing particle once, in t order.
fn assert_queries_match_brute(g: &ParticleGrid, ray: &RaySegment, rc: f64) {
    assert_eq!(g.occupied_interval(ray), g.occupied_interval_brute(ray));
    let mut walked = Vec::new();
    g.walk(ray, |t, _, i| {
        walked.push((t, i));
        true
    });
    assert!(
        walked.windows(2).all(|w| w[0].0 <= w[1].0),
        "walk out of order"
    );
    let mut expect = Vec::new();
    for c in &g.classes {
        c.each_particle(
            |(centre, r), _, i| match ball_contribution(centre, r, ray) {
                Some(t) if ray.contains(t) => expect.push(i),
                _ => {}
            },
        );
    }
    let mut got: Vec<u32> = walked.iter().map(|w| w.1).collect();
    got.sort();
    expect.sort();
    let RaySegment { o, d, t0, t1 } = *ray;
    assert_eq!(got, expect, "walk rc={rc} o={o:?} d={d:?}");
    let (mut a, mut b) = (vec![0.0; 2], vec![0.0; 2]);
    g.optical_depth(ray, &mut a);
    g.optical_depth_brute(ray, &mut b);
    for ch in 0..2 {
        assert!(
            (a[ch] - b[ch]).abs() <= 1e-9 * b[ch].abs().max(1e-300),
            "rc={rc} o={o:?} d={d:?} [{t0},{t1}) grid {} brute {}",
            a[ch],
            b[ch]
        );
    }
}

/// 3000 random particles with two channels of cross sections (the brute-force tests' set).
fn two_channel_particles(s: &mut u64) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
    let (pos, rad) = random_particles(s, 3000, 0.001, 0.02);
    let cext = rad
        .iter()
        .flat_map(|r| [2.0 * PI * r * r, 3.0 * r * r])
        .collect();
    (pos, rad, cext)
}

/// Every contribution a walk reports along `ray`: (t, τ per channel, `name` of the particle).
fn walk_hits(
    g: &ParticleGrid,
    ray: &RaySegment,
    name: impl Fn(u32) -> u32,
) -> Vec<(f64, Vec<f32>, u32)> {
    let mut h = Vec::new();
    g.walk(ray, |t, tau, i| {
        h.push((t, tau.to_vec(), name(i)));
        true
    });
    h
}

/// Grids of particles (`pos`, `rad`, `cext` of two channels) in the layouts (query radius, cells
/// per particle, quantised, centre cells) `layouts`.
fn grids_of<'a>(
    pos: &'a [[f64; 3]],
    rad: &'a [f64],
    cext: &'a [f64],
    layouts: &'a [(f64, f64, bool, bool)],
) -> impl Iterator<Item = ((f64, f64, bool, bool), ParticleGrid)> + 'a {
    layouts.iter().map(move |&(rc, cpp, quantise, centred)| {
        let settings = GridSettings::new(rc, cpp)
            .quantised(quantise)
            .centred(centred);
        let g = ParticleGrid::build(pos, rad, cext, 2, &settings).unwrap();
        ((rc, cpp, quantise, centred), g)
    })
}

/// A grid whose sparse classes released their stored copies (what a medium keeps) answers every
/// query as before, its oracles read the slots, and it keeps fewer bytes.
#[test]
fn released_grid_answers_the_same() {
    let mut s = 5u64;
    let (pos, rad, cext) = two_channel_particles(&mut s);
    let layouts = [
        (0.01, 1.0, false, false),
        (0.0, 20.0, false, false),
        (0.01, 1.0, true, false),
        (0.0, 20.0, true, false),
        (0.01, 1.0, true, true),
    ];
    let released = grids_of(&pos, &rad, &cext, &layouts).map(|(_, mut r)| {
        r.release_stored();
        r
    });
    for (((.., centred), g), r) in grids_of(&pos, &rad, &cext, &layouts).zip(released) {
        // Centred classes store each particle once: nothing to release.
        assert!(r.bytes() < g.bytes() || centred && r.bytes() == g.bytes());
        assert_eq!(r.len(), g.len());
        let frame = &g.classes[0].frame;
        for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
            assert_eq!(walk_hits(&g, ray, |i| i), walk_hits(&r, ray, |i| i));
            let (mut x, mut y) = (vec![0.0; 2], vec![0.0; 2]);
            g.optical_depth_brute(ray, &mut x);
            r.optical_depth_brute(ray, &mut y);
            assert!((0..2).all(|ch| (x[ch] - y[ch]).abs() <= 1e-12 * x[ch].abs().max(1e-300)));
            assert_eq!(
                g.occupied_interval_brute(ray),
                r.occupied_interval_brute(ray)
            );
        }
        for _ in 0..100 {
            let p = [lcg(&mut s), lcg(&mut s), lcg(&mut s)];
            let (mut a, mut b) = (g.containing_brute(p), r.containing_brute(p));
            a.sort();
            b.sort();
            assert_eq!(a, b);
            assert_eq!(g.containing(p), r.containing(p));
        }
        for i in [0u32, 17, 2999] {
            assert_eq!(g.tau_of(i, 1), r.tau_of(i, 1));
        }
    }
}

/// Centre-cell classes walked in prefetched batches (the path of clouds whose slots outgrow the
/// cache) report what the O(N) loop finds, as the cached walk does.
#[test]
fn batched_centre_cell_walks_equal_brute_force() {
    let mut s = 19u64;
    let (pos, rad, cext) = two_channel_particles(&mut s);
    let layouts = [
        (0.01, 1.0, true, true),
        (0.2, 5.0, true, true),
        (0.0, 20.0, false, true),
    ];
    for ((rc, ..), g) in grids_of(&pos, &rad, &cext, &layouts) {
        let g = g.batched();
        let frame = &g.classes[0].frame;
        for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
            assert_queries_match_brute(&g, ray, rc);
        }
    }
}

/// A beam's free flights equal each ray's own ([`ParticleGrid::sample_site`]): the same sites and
/// optical depths, for a pixel's camera rays from outside the grid, shadow rays from nearby
/// points converging on a light, rays from inside the grid and rays that miss it, with flights
/// that stop at once and flights that pass every particle; in centre cells quantised or not, with
/// AVX2 and without; beams over the whole segments and beams cut short (their rays walking on
/// alone past the cut). Rays that diverge from the start are no beam.
#[test]
fn beams_sample_each_rays_own_free_flight() {
    if !crate::simd::wide_simd() {
        crate::simd::say_simd_half_not_run(
            "beams_sample_each_rays_own_free_flight",
            "no AVX2 + FMA walk here (CPU or MOTES_SIMD): every beam ran the narrow walk",
        );
    } else if !crate::simd::lockstep_simd() {
        crate::simd::say_simd_half_not_run(
            "beams_sample_each_rays_own_free_flight",
            "no AVX-512 here (CPU or MOTES_SIMD): no beam tested its rays side by side",
        );
    }
    let mut s = 29u64;
    let n = 20_000;
    let pos = random_points(&mut s, n);
    // One size class (radii within a factor of two).
    let rad: Vec<f64> = (0..n).map(|_| 0.004 + 0.003 * lcg(&mut s)).collect();
    let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
    let (mut beams, mut rays_checked, mut wide, mut cut, mut odd_beams) = (0, 0, 0, 0, 0);
    for (quantise, simd) in [(true, true), (false, true), (true, false)] {
        let settings = GridSettings::new(0.01, 0.25)
            .quantised(quantise)
            .centred(true);
        let g = ParticleGrid::build(&pos, &rad, &cext, 1, &settings).unwrap();
        assert_eq!(g.class_count(), 1);
        let norm = |v: [f64; 3]| {
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / l)
        };
        for b in 0..120 {
            let k = 2 + (lcg(&mut s) * 15.0) as usize;
            // Spreads from far below the balls' reach to beyond a cell.
            let spread = 0.002 * 30f64.powf(lcg(&mut s));
            let target = [0, 1, 2].map(|_| 1.2 * lcg(&mut s) - 0.1);
            let rays: Vec<RaySegment> = match b % 3 {
                // A pixel's camera rays: one eye, directions a few mrad apart (or, from an eye
                // at the box, ten times as many: they spread across the box, and make a beam
                // over its first part only).
                0 => {
                    let (z, wider) = if b % 2 == 0 {
                        (-3.0, 1.0)
                    } else {
                        (-0.05, 4.0)
                    };
                    let eye = [0.5 + 0.3 * lcg(&mut s), 0.4, z];
                    (0..k)
                        .map(|_| {
                            let aim = target.map(|x| x + wider * spread * (lcg(&mut s) - 0.5));
                            let d = norm([0, 1, 2].map(|a| aim[a] - eye[a]));
                            RaySegment::new(eye, d, 0.0, 10.0)
                        })
                        .collect()
                }
                // Shadow rays from points of a small spot towards a light far away.
                1 => {
                    let light = [3.0, 4.0, 2.0];
                    (0..k)
                        .map(|_| {
                            let o = target.map(|x| x + spread * (lcg(&mut s) - 0.5));
                            let d = [0, 1, 2].map(|a| light[a] - o[a]);
                            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                            RaySegment::new(o, d.map(|x| x / l), 0.0, l)
                        })
                        .collect()
                }
                // Axis-aligned rays starting part-way along (t0 > 0).
                2 if b % 2 == 0 => {
                    let o = [target[0], target[1], -1.0];
                    (0..k)
                        .map(|_| {
                            let o = [o[0] + spread * (lcg(&mut s) - 0.5), o[1], o[2]];
                            RaySegment::new(o, [0.0, 0.0, 1.0], 0.5 + 0.5 * lcg(&mut s), 3.0)
                        })
                        .collect()
                }
                // Rays leaving the grid's neighbourhood, some missing it.
                _ => {
                    let o = [0.5, 0.5, 0.5].map(|x: f64| x + 0.9 * (lcg(&mut s) - 0.5));
                    let d0 = norm([lcg(&mut s) - 0.5, lcg(&mut s) - 0.5, lcg(&mut s) - 0.5]);
                    (0..k)
                        .map(|i| {
                            let d = norm(d0.map(|x| x + 0.002 * (lcg(&mut s) - 0.5)));
                            let o = o.map(|x| x + spread * (lcg(&mut s) - 0.5));
                            let o = if i % 5 == 4 { o.map(|x| x + 3.0) } else { o };
                            RaySegment::new(o, d, 0.0, 2.0)
                        })
                        .collect()
                }
            };
            let us: Vec<f64> = (0..k)
                .map(|i| match i % 4 {
                    0 => 0.999_999,
                    1 => 1e-9,
                    _ => lcg(&mut s),
                })
                .collect();
            let mut out = vec![(None, -1.0); k];
            let ran = if simd {
                g.sample_sites_beam(&rays, &us, 1e-6, &mut out)
            } else {
                g.beam_lanes::<false>(&rays, &us, 1e-6, &mut out)
            };
            if !ran {
                continue;
            }
            beams += 1;
            let beam = g.classes[0].beam(&rays, &mut [None; BEAM_RAYS]).unwrap();
            wide += (beam.delta > 0.5 * g.classes[0].reach_max) as usize;
            cut += beam.cut.iter().any(|c| c.is_finite()) as usize;
            for i in 0..k {
                let (site, tau) = g.sample_site(&rays[i], &[], us[i], 1e-6);
                assert_eq!(out[i].0, site, "beam {b}, ray {i}");
                assert_eq!(out[i].1, tau, "beam {b}, ray {i}");
                rays_checked += 1;
            }
        }
        // Rays in all directions are no beam.
        let spread: Vec<RaySegment> = (0..8)
            .map(|i| {
                let a = i as f64;
                RaySegment::new([0.5; 3], norm([a.cos(), a.sin(), 0.3]), 0.0, 2.0)
            })
            .collect();
        let mut out = vec![(None, 0.0); 8];
        assert!(!g.sample_sites_beam(&spread, &[0.5; 8], 1e-6, &mut out));
        // Nor rays one of which has a NaN origin.
        let d = norm([0.1, 0.2, 1.0]);
        let nan = [
            RaySegment::new([0.4, 0.3, -1.0], d, 0.0, 3.0),
            RaySegment::new([f64::NAN, 0.3, -1.0], d, 0.0, 3.0),
        ];
        assert!(!g.sample_sites_beam(&nan, &[0.5; 2], 1e-6, &mut out));
        // Rays with a NaN end or an empty segment among others: nothing for them, the others
        // their own sites (the box's clip drops a NaN end: such a ray must not walk).
        let odd = [
            RaySegment::new([0.4, 0.3, -1.0], d, 0.0, 3.0),
            RaySegment::new([0.4, 0.3, -1.0], d, 0.0, f64::NAN),
            RaySegment::new([0.4, 0.3, -1.0], d, f64::NAN, 3.0),
            RaySegment::new([0.4, 0.3, -1.0], d, 2.0, 1.0),
            RaySegment::new([0.41, 0.3, -1.0], d, 0.0, 3.0),
        ];
        let us = [0.999_999, 0.5, 0.5, 0.5, 0.3];
        let mut out = vec![(None, -1.0); odd.len()];
        if g.sample_sites_beam(&odd, &us, 1e-6, &mut out) {
            for i in 0..odd.len() {
                assert_eq!(out[i], g.sample_site(&odd[i], &[], us[i], 1e-6), "ray {i}");
            }
            odd_beams += 1;
        }
    }
    assert!(odd_beams > 0);
    assert!(
        beams > 200 && wide > 60 && cut > 30,
        "{beams} beams, {wide} wider than half the reach, {cut} cut short"
    );
    assert!(rays_checked > 1500);
}

/// Quantised centres on cell faces: each is stored in the cell its lattice coordinates give, so
/// its slots read the same centre from the corners of every row that holds its cell (the first,
/// second or third cell of a row), and the walk finds what the O(N) loop finds. (Cells chosen in
/// floating point put ~8 % of such centres one cell low, read 4 cells away from a row's corner.)
#[test]
fn centres_on_cell_faces_stay_in_their_cells() {
    let mut s = 23u64;
    let settings = GridSettings::new(0.01, 1.0).quantised(true).centred(true);
    let mut checked = 0;
    // Clouds of their own (each face rounds its own way), every particle but the box's extremes
    // moved onto the nearest face of the grid's cells along x, then y (the box, hence the grid,
    // stays the same).
    for axis in [0, 1, 0, 1, 0, 1] {
        let (mut pos, rad, cext) = two_channel_particles(&mut s);
        let g = ParticleGrid::build(&pos, &rad, &cext, 2, &settings).unwrap();
        let frame = g.classes[0].frame;
        let (lo, hi) = bounding_box(&pos);
        for p in pos.iter_mut() {
            if (0..3).all(|a| p[a] > lo[a] && p[a] < hi[a]) {
                let k = ((p[axis] - frame.bounds.lo[axis]) / frame.cell[axis]).round();
                p[axis] = (frame.bounds.lo[axis] + k * frame.cell[axis]).clamp(lo[axis], hi[axis]);
            }
        }
        let g = ParticleGrid::build(&pos, &rad, &cext, 2, &settings).unwrap();
        assert_eq!(g.classes.len(), 1);
        let c = &g.classes[0];
        assert_eq!(
            (c.frame.bounds.lo, c.frame.cell),
            (frame.bounds.lo, frame.cell)
        );
        let q = c.quant.as_ref().expect("quantised");
        let dims = c.frame.dims;
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let i = (z * dims[1] + y) * dims[0] + x;
                    for sl in c.start[i] as usize..c.start[i + 1] as usize {
                        let own = q.lattice(sl, [x, y, z]);
                        for first in x.saturating_sub(2)..=x {
                            assert_eq!(q.lattice(sl, [first, y, z]), own, "cell {x} {y} {z}");
                        }
                        checked += 1;
                    }
                }
            }
        }
        let batched = ParticleGrid::build(&pos, &rad, &cext, 2, &settings)
            .unwrap()
            .batched();
        for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
            assert_queries_match_brute(&g, ray, 0.01);
            assert_queries_match_brute(&batched, ray, 0.01);
        }
    }
    assert_eq!(checked, 6 * 3000);
}

/// A positional grid (`ParticleGrid::positional`) reports the same particles in the same order,
/// named by their positions, which its order maps back to the original indices; centre-cell
/// classes then keep no index.
#[test]
fn positional_ids_name_the_same_particles() {
    let mut s = 13u64;
    let (pos, rad, cext) = two_channel_particles(&mut s);
    let layouts = [
        (0.01, 1.0, true, false),
        (0.0, 20.0, false, false),
        (0.01, 1.0, true, true),
        (0.2, 5.0, true, true),
        (0.01, 1.0, false, true),
    ];
    let positional = grids_of(&pos, &rad, &cext, &layouts).map(|(_, g)| {
        let (mut p, order) = g.positional();
        p.release_stored();
        (p, order)
    });
    for (((.., centred), g), (p, order)) in grids_of(&pos, &rad, &cext, &layouts).zip(positional) {
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert!(sorted.iter().enumerate().all(|(j, &i)| j as u32 == i));
        if centred {
            assert!(
                p.bytes() + 4 * pos.len() <= g.bytes(),
                "{} {}",
                p.bytes(),
                g.bytes()
            );
        }
        let frame = &g.classes[0].frame;
        for ray in &test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]) {
            assert_eq!(
                walk_hits(&g, ray, |i| i),
                walk_hits(&p, ray, |j| order[j as usize])
            );
        }
        for _ in 0..100 {
            let q = [lcg(&mut s), lcg(&mut s), lcg(&mut s)];
            let mut a = g.containing(q);
            let mut b: Vec<u32> = p.containing(q).iter().map(|&j| order[j as usize]).collect();
            a.sort();
            b.sort();
            assert_eq!(a, b);
        }
    }
}

/// The AVX2 walk (where the CPU has it, whatever `MOTES_SIMD` says) and the SSE/scalar one report
/// the same hits, in the same order, on sparse and dense classes and on rays along the axes.
#[test]
fn wide_and_narrow_walks_agree() {
    #[cfg(target_arch = "x86_64")]
    let cpu_has_wide = crate::simd::cpu_has_wide();
    #[cfg(not(target_arch = "x86_64"))]
    let cpu_has_wide = false;
    if !cpu_has_wide {
        crate::simd::say_simd_half_not_run(
            "wide_and_narrow_walks_agree",
            "no AVX2 + FMA on this CPU (only the narrow walk ran)",
        );
    }
    let mut s = 11u64;
    let (pos, rad) = random_particles(&mut s, 3000, 0.001, 0.02);
    let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
    for (rc, cpp, quantise, centred) in [
        (0.01, 1.0, false, false),
        (0.0, 0.125, false, false),
        (0.2, 5.0, false, false),
        (0.0, 20.0, false, false),
        (0.01, 1.0, true, false),
        (0.0, 0.125, true, false),
        (0.0, 20.0, true, false),
        (0.01, 1.0, true, true),
        (0.0, 0.125, true, true),
        (0.2, 5.0, true, true),
    ] {
        let settings = GridSettings::new(rc, cpp)
            .quantised(quantise)
            .centred(centred);
        let g = ParticleGrid::build(&pos, &rad, &cext, 1, &settings).unwrap();
        let frame = &g.classes[0].frame;
        let rays = test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]);
        let hits = |wide: bool, ray: &RaySegment| {
            let _ = wide; // read only on x86_64
            let mut h = Vec::new();
            let record = |t: f64, tau: &[f32], i: u32| {
                h.push((t, tau[0], i));
                true
            };
            #[cfg(target_arch = "x86_64")]
            if wide {
                // SAFETY: only where the CPU has AVX2 and FMA.
                unsafe { g.walk_avx2(ray, record) };
                return h;
            }
            g.walk_lanes::<false>(ray, record);
            h
        };
        let mut total = 0;
        for ray in &rays {
            let narrow = hits(false, ray);
            total += narrow.len();
            if cpu_has_wide {
                assert_eq!(hits(true, ray), narrow, "rc={rc} cpp={cpp} ray={ray:?}");
            }
        }
        assert!(total > 0, "the rays must hit something");
    }
}

/// Grid traversal equals the O(N) loop for random rays, axis-aligned rays, rays starting inside,
/// rays on cell faces, zero-length segments and rays missing the grid.
#[test]
fn grid_equals_brute_force() {
    let mut s = 7u64;
    let (pos, rad, cext) = two_channel_particles(&mut s);
    for ((rc, cpp), quantise, centred) in [
        (0.0, 1.0),
        (0.01, 1.0),
        (0.05, 0.2),
        (0.2, 5.0),
        (0.0, 0.25),
        (0.0, 20.0),
    ]
    .into_iter()
    .flat_map(|x| {
        [
            (x, false, false),
            (x, true, false),
            (x, true, true),
            (x, false, true),
        ]
    }) {
        let settings = GridSettings::new(rc, cpp)
            .quantised(quantise)
            .centred(centred);
        let g = ParticleGrid::build(&pos, &rad, &cext, 2, &settings).unwrap();
        assert!(
            g.classes.iter().all(|c| c.quant.is_some() == quantise),
            "classes are quantised exactly when asked"
        );
        assert!(!centred || g.classes.iter().all(|c| c.k == 1));
        if rc == 0.0 && cpp == 1.0 {
            // Every class is sparse at this resolution: one grid (merge_sparse_classes).
            assert_eq!(g.class_count(), 1);
        }
        if cpp == 20.0 {
            // Fine cells make the largest grains a dense class apart from the sparse rest.
            assert!(g.class_count() > 1, "the test needs several size classes");
        }
        let frame = &g.classes[0].frame;
        let rays = test_rays(&mut s, frame.bounds.lo[0], frame.cell[0]);
        for _ in 0..200 {
            let p = [
                lcg(&mut s) * 1.4 - 0.2,
                lcg(&mut s) * 1.4 - 0.2,
                lcg(&mut s) * 1.4 - 0.2,
            ];
            let (mut a, mut b) = (g.containing(p), g.containing_brute(p));
            a.sort();
            b.sort();
            assert_eq!(a, b, "containing({p:?}) rc={rc}");
        }
        for ray in &rays {
            assert_queries_match_brute(&g, ray, rc);
        }
    }
}

/// Quantised slots (compact storage) move each centre by at most half a lattice step (6·10⁻⁵ of a
/// cell), keep every particle, and take fewer bytes than spheres; a class with more distinct
/// (R, τ) than a u16 code holds keeps spheres.
#[test]
fn quantised_slots_stay_on_their_particles() {
    let mut s = 3u64;
    let (pos, rad) = random_particles(&mut s, 3000, 0.001, 0.02);
    let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
    let settings = GridSettings::new(0.01, 1.0);
    let full = ParticleGrid::build(&pos, &rad, &cext, 1, &settings).unwrap();
    let q = ParticleGrid::build(&pos, &rad, &cext, 1, &settings.quantised(true)).unwrap();
    let c = &q.classes[0];
    let step = c.quant.as_ref().expect("a sparse class, quantised").step;
    assert!(step < 1e-4 * c.frame.cell[0]);
    let mut seen = 0;
    c.each_particle(|(centre, r), _, i| {
        seen += 1;
        for a in 0..3 {
            let d = (centre[a] - pos[i as usize][a]).abs();
            assert!(
                d <= 0.5 * step * (1.0 + 1e-6),
                "particle {i} moved {d} (step {step})"
            );
        }
        assert!((r - (0.01 + rad[i as usize])).abs() < 1e-6 * r);
    });
    assert_eq!(seen, pos.len());
    let (mut qr, mut fr) = (q, full);
    qr.release_stored();
    fr.release_stored();
    assert!(
        (qr.bytes() as f64) < 0.6 * fr.bytes() as f64,
        "{} vs {}",
        qr.bytes(),
        fr.bytes()
    );
    // More distinct (R, τ) than codes: spheres, still answering as the oracle does.
    let n = 70_000;
    let (pos, _) = random_particles(&mut s, n, 0.001, 0.002);
    let rad: Vec<f64> = (0..n).map(|i| 1e-4 * (1.0 + i as f64 / n as f64)).collect();
    let cext: Vec<f64> = rad.iter().map(|r| 2.0 * PI * r * r).collect();
    let exact_radii = GridSettings::new(0.0, 1.0).quantised(true);
    let g = ParticleGrid::build(&pos, &rad, &cext, 1, &exact_radii).unwrap();
    assert!(g.classes.iter().all(|c| c.k == 0 && c.quant.is_none()));
    let frame = &g.classes[0].frame;
    for ray in test_rays(&mut s, frame.bounds.lo[0], frame.cell[0])
        .iter()
        .take(50)
    {
        assert_queries_match_brute(&g, ray, 0.0);
    }
}

/// Every stored bit of a grid's classes (each list behind its length), to compare two builds.
fn fingerprint(g: &ParticleGrid) -> Vec<u64> {
    let mut v = vec![g.classes.len() as u64, g.n as u64, g.channels as u64];
    let f32s = |v: &mut Vec<u64>, x: &[f32]| {
        v.push(x.len() as u64);
        v.extend(x.iter().map(|a| a.to_bits() as u64));
    };
    let u32s = |v: &mut Vec<u64>, x: &[u32]| {
        v.push(x.len() as u64);
        v.extend(x.iter().map(|&a| a as u64));
    };
    for c in &g.classes {
        for spheres in [&c.particles, &c.inline] {
            v.push(spheres.0.len() as u64);
            for b in &spheres.0 {
                for x in [&b.x, &b.y, &b.z, &b.r] {
                    f32s(&mut v, x);
                }
            }
        }
        f32s(&mut v, &c.tau);
        u32s(&mut v, &c.index);
        u32s(&mut v, &c.start);
        f32s(&mut v, &c.slot_tau);
        u32s(&mut v, &c.slot_index);
        match &c.quant {
            Some(q) => {
                v.push(q.blocks.len() as u64);
                for b in &q.blocks {
                    for x in [&b.x, &b.y, &b.z, &b.code] {
                        v.extend(x.iter().map(|&a| a as u64));
                    }
                }
                f32s(&mut v, &q.block_reach);
                f32s(&mut v, &q.reach);
                f32s(&mut v, &q.tau);
                v.push(q.step.to_bits());
            }
            None => v.push(u64::MAX),
        }
        let f = &c.frame;
        v.extend(
            f.bounds
                .lo
                .iter()
                .chain(&f.bounds.hi)
                .chain(&f.cell)
                .map(|x| x.to_bits()),
        );
        v.extend(f.dims.iter().map(|&d| d as u64));
        v.extend([
            c.channels as u64,
            c.reach_max.to_bits(),
            c.k as u64,
            c.prefetch_slots as u64,
            c.count as u64,
            c.first_id as u64,
        ]);
    }
    v
}

/// A grid built on one thread and on several is the same grid, bit for bit (cells, the particles'
/// order within them, slots, codes, positional order): random clouds of several size classes in
/// every layout (centre cells and overlap slots, quantised or spheres), every grain in one cell, one
/// grain, and grains on cell faces (a lattice of the cells' own spacing).
#[test]
fn parallel_builds_equal_one_thread() {
    let mut s = 23u64;
    let n = 150_000;
    let (random, rad) = random_particles(&mut s, n, 0.0005, 0.004);
    let one_cell = vec![[0.25, 0.5, 0.75]; 100_000];
    let faces: Vec<[f64; 3]> = (0..80_000)
        .map(|i| {
            [
                (i % 40) as f64 * 0.025,
                ((i / 40) % 40) as f64 * 0.025,
                (i / 1600) as f64 * 0.02,
            ]
        })
        .collect();
    // Radii with many ties (a few values), as compact storage's classes make them.
    let tied: Vec<f64> = (0..n).map(|i| 0.0005 * (1 + i % 7) as f64).collect();
    let clouds: Vec<(&[[f64; 3]], &[f64])> = vec![
        (&random, &rad),
        (&random, &tied),
        (&one_cell, &tied[..100_000]),
        (&faces, &tied[..80_000]),
        (&random[..1], &rad[..1]),
    ];
    for (pos, r) in clouds {
        let cext: Vec<f64> = r.iter().map(|r| 2.0 * PI * r * r).collect();
        for (quantise, centred) in [(true, true), (true, false), (false, false), (false, true)] {
            let settings = GridSettings::new(0.001, DEFAULT_CELLS_PER_PARTICLE)
                .quantised(quantise)
                .centred(centred)
                .by_free_path(true);
            let build = || {
                let g = ParticleGrid::build(pos, r, &cext, 1, &settings).unwrap();
                let (p, order) = ParticleGrid::build(pos, r, &cext, 1, &settings)
                    .unwrap()
                    .positional();
                (fingerprint(&g), fingerprint(&p), order)
            };
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap()
                .install(build);
            for threads in [2, 4] {
                let many = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(build);
                assert!(
                    one == many,
                    "{} grains, quantise {quantise}, centred {centred}, {threads} threads",
                    pos.len()
                );
            }
        }
    }
}
