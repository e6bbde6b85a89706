use super::flight::ln_unit;
use super::*;

use crate::rng::stream_bits;
use crate::space::ray::RaySegment;
use crate::space::vec3;
use crate::test_rng::{assert_escape_rate, lcg, random_points};
use std::sync::atomic::Ordering;

/// The field's optical depth along long rays through a uniform random cloud equals σ_t L (the
/// particles' summed extinction over the volume), free flights escape with probability e^{−τ},
/// and picks follow each cell's extinction shares.
#[test]
fn field_is_the_mean_of_the_particles() {
    let mut s = 5u64;
    let n = 200_000;
    let pos = random_points(&mut s, n);
    let reach = vec![0.01; n];
    let w: Vec<f64> = (0..n).map(|_| 1e-5 * (0.5 + lcg(&mut s))).collect();
    let ids: Vec<u32> = (0..n as u32).collect();
    let f = ContinuousField::build(&pos, &|i| reach[i], &|i| w[i], Some(&ids), None).unwrap();
    let sigma = w.iter().sum::<f64>(); // volume 1
    let ray = RaySegment::new([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], 0.0, 3.0);
    let tau = f.optical_depth(&ray);
    assert!((tau / sigma - 1.0).abs() < 0.1, "{tau} vs {sigma}");
    let mut mean = 0.0;
    for _ in 0..200 {
        let o = [lcg(&mut s), lcg(&mut s), -1.0];
        mean += f.optical_depth(&RaySegment { o, ..ray }) / 200.0;
    }
    assert!((mean / sigma - 1.0).abs() < 0.02, "{mean} vs {sigma}");
    assert_escape_rate(&mut s, 20_000, (-tau).exp(), |u| {
        let (hit, walked) = f.free_flight(&ray, -(1.0 - u).ln());
        if let Some(h) = hit {
            assert!(h.t >= 0.95 && h.t <= 2.05, "{}", h.t); // the box, to a cell (~0.034)
            let before = f.optical_depth(&ray.between(0.0, h.t));
            assert!((before - walked).abs() < 1e-6 * tau.max(1.0));
        } else {
            assert!((walked - tau).abs() < 1e-9);
        }
        hit.is_none()
    });
    let c = f.cell_at([0.5, 0.5, 0.5]).unwrap();
    let m: Vec<u32> = f.members(c).collect();
    assert!(!m.is_empty());
    let total: f64 = m.iter().map(|&i| w[i as usize]).sum();
    let mut counts = vec![0usize; m.len()];
    let picks = 40_000;
    for _ in 0..picks {
        let i = f.pick(c, lcg(&mut s)).unwrap();
        counts[m.iter().position(|&x| x == i).unwrap()] += 1;
    }
    for (k, &i) in m.iter().enumerate() {
        let p = w[i as usize] / total;
        let sd = (p * (1.0 - p) / picks as f64).sqrt();
        assert!((counts[k] as f64 / picks as f64 - p).abs() < 5.0 * sd);
    }
}

/// A packet's free flights stepped together give each ray exactly the hit it gets alone (with the
/// same exponentials), on every CPU (the lockstep forced, lane by lane without AVX-512) and as the
/// CPU runs them: rays starting inside, outside and on the box, leaving it, ending inside it, along
/// axes; one field majorant, blocks, and one majorant with cells 5 % too small for the box (tentative
/// collisions then fall outside the cells before the box's exit, and those lanes go on one ray at a
/// time, which rounding at a face causes only now and then); packets of 1 to 24 rays.
#[test]
fn packet_free_flights_match_one_ray_at_a_time() {
    if !crate::simd::lockstep_simd() {
        crate::simd::say_simd_half_not_run(
            "packet_free_flights_match_one_ray_at_a_time",
            "no AVX-512 here (CPU or MOTES_SIMD): the forced lockstep ran lane by lane",
        );
    }
    let mut s = 23u64;
    let mut f = ContinuousField::build(
        &random_points(&mut s, 30_000),
        &|_| 0.02,
        &|_| 1e-4,
        None,
        None,
    )
    .unwrap();
    let largest = f.majorant.iter().fold(0.0f64, |x, &m| x.max(m as f64));
    let inv_cell = f.inv_cell;
    let continued_before = CONTINUED.load(Ordering::Relaxed);
    let mut hits = 0;
    for (uniform, shrink) in [(Some(largest), 1.0), (None, 1.0), (Some(largest), 1.05)] {
        f.uniform_majorant = uniform;
        f.inv_cell = inv_cell.map(|x| x * shrink);
        for trial in 0..400 {
            let n = 1 + trial % (FLIGHT_LANES + 8); // 17 to 24: two packets
            let rays: Vec<RaySegment> = (0..n)
                .map(|k| {
                    let o = match k % 4 {
                        0 => [lcg(&mut s), lcg(&mut s), lcg(&mut s)],
                        1 => [3.0 * lcg(&mut s) - 1.0, 3.0 * lcg(&mut s) - 1.0, -1.0],
                        2 => [0.0, lcg(&mut s), lcg(&mut s)], // on a face
                        _ => [0.5, 0.5, 0.5],
                    };
                    let d = if k % 5 == 4 {
                        [0.0, 0.0, 1.0]
                    } else {
                        let v = [0; 3].map(|_| 2.0 * lcg(&mut s) - 1.0);
                        let l = vec3::dot(v, v).sqrt().max(1e-3);
                        v.map(|x| x / l)
                    };
                    RaySegment::new(o, d, 0.0, [0.3, 1.0, 10.0][k % 3])
                })
                .collect();
            let keys: Vec<u64> = (0..n)
                .map(|_| (lcg(&mut s) * 2f64.powi(62)) as u64)
                .collect();
            let mut forced = vec![None; n];
            for a in (0..n).step_by(FLIGHT_LANES) {
                let b = (a + FLIGHT_LANES).min(n);
                f.sample_packet_flights_with(&rays[a..b], &keys[a..b], &mut forced[a..b], true);
            }
            let mut as_run = vec![None; n];
            f.sample_free_flights(&rays, &keys, &mut as_run);
            for i in 0..n {
                let mut k = 0u64;
                let mut next = || {
                    k += 1;
                    stream_bits(keys[i], 1 + k)
                };
                // A packet of one ray (the last of 17) flies it alone, libm's way.
                let packet = n - i / FLIGHT_LANES * FLIGHT_LANES;
                let lockstep = packet > 1 && f.uniform_majorant.is_some();
                let alone = if lockstep {
                    f.free_flight_by::<true>(&rays[i], &mut next)
                } else {
                    f.sample_free_flight(&rays[i], &mut next)
                };
                assert_eq!(forced[i], alone, "ray {i} of {n}: {:?}", rays[i]);
                if f.flies_in_lockstep() || !lockstep {
                    assert_eq!(as_run[i], alone, "ray {i} of {n}: {:?}", rays[i]);
                }
                hits += alone.is_some() as usize;
            }
        }
    }
    assert!(hits > 500, "{hits}"); // both outcomes exercised
    let continued = CONTINUED.load(Ordering::Relaxed) - continued_before;
    assert!(continued > 20, "{continued}"); // and the continuation one ray at a time
}

/// The exponential's logarithm against libm's over (0, 1], the ends included.
#[test]
fn ln_unit_matches_libm() {
    let mut s = 3u64;
    let mut xs: Vec<f64> = (0..100_000)
        .map(|_| lcg(&mut s))
        .filter(|&x| x > 0.0)
        .collect();
    xs.extend([
        1.0,
        0.5,
        std::f64::consts::FRAC_1_SQRT_2,
        1.0 - f64::EPSILON,
        1.16e-10,
        0.5 / 4294967296.0,
    ]);
    for x in xs {
        let (a, b) = (ln_unit(x), x.ln());
        assert!(
            (a - b).abs() <= 1e-13 * b.abs().max(1e-300) + 1e-300,
            "{x}: {a} vs {b}"
        );
    }
}

/// Delta tracking against the majorant blocks samples the same free-flight distribution as the
/// cell-by-cell walk: P(t_hit < t) = 1 − exp(−τ(0, t)) on a cloud whose density rises steeply
/// along the ray (z³: majorants far above most cells' σ_t), along and across the gradient, with
/// rays starting inside and outside the box.
#[test]
fn delta_tracking_samples_the_exact_free_flight() {
    let mut s = 11u64;
    let n = 100_000;
    let pos: Vec<[f64; 3]> = random_points(&mut s, n)
        .into_iter()
        .map(|p| [p[0], p[1], p[2].cbrt()])
        .collect();
    let reach = vec![0.01; n];
    let w = vec![3e-5; n];
    let ids: Vec<u32> = (0..n as u32).collect();
    let mut f = ContinuousField::build(&pos, &|i| reach[i], &|i| w[i], Some(&ids), None).unwrap();
    // Both ways: the blocks' majorants, and the whole field's (which this gradient's field would
    // not choose, but is as exact).
    let largest = f.majorant.iter().fold(0.0f64, |x, &m| x.max(m as f64));
    for uniform in [None, Some(largest)] {
        f.uniform_majorant = uniform;
        delta_tracking_matches_exact(&f, &mut s);
    }
    // A cloud of even density takes the whole field's majorant.
    let even = ContinuousField::build(
        &random_points(&mut s, 20_000),
        &|_| 0.01,
        &|_| 3e-5,
        None,
        None,
    )
    .unwrap();
    assert!(even.uniform_majorant.is_some());
    delta_tracking_matches_exact(&even, &mut s);
    // All particles in one corner block of a large box: blocks.
    let mut corner = random_points(&mut s, 20_000);
    corner.iter_mut().for_each(|p| *p = p.map(|x| 0.05 * x));
    corner.push([1.0; 3]);
    let crowded = ContinuousField::build(&corner, &|_| 0.01, &|_| 3e-5, None, None).unwrap();
    assert!(crowded.uniform_majorant.is_none());
}

/// [`ContinuousField::sample_free_flight`]'s distribution against the exact optical depth along
/// four rays.
fn delta_tracking_matches_exact(f: &ContinuousField, s: &mut u64) {
    let rays = [
        RaySegment::new([0.5, 0.5, -1.0], [0.0, 0.0, 1.0], 0.0, 3.0),
        RaySegment::new([0.3, 0.7, 0.2], [0.0, 0.0, 1.0], 0.0, 3.0),
        RaySegment::new([-0.5, 0.4, 0.9], [0.8, 0.0, -0.6], 0.0, 4.0),
        RaySegment::new([0.5, 0.5, 2.0], [0.0, 0.6, -0.8], 0.0, 5.0),
    ];
    for ray in rays {
        let trials = 40_000;
        let mut times = Vec::with_capacity(trials);
        for _ in 0..trials {
            let mut seed = (lcg(s) * 2f64.powi(52)) as u64;
            let hit = f.sample_free_flight(&ray, || {
                seed = seed.wrapping_add(crate::rng::GOLDEN_GAMMA);
                crate::rng::splitmix64_finalise(seed)
            });
            if let Some(h) = hit {
                assert!(f.sigma[h.cell] > 0.0 && h.t >= ray.t0 && h.t <= ray.t1);
                times.push(h.t);
            }
        }
        for q in [0.2, 0.4, 0.6, 0.8, 1.0] {
            let t = ray.t0 + q * (ray.t1 - ray.t0);
            let expect = 1.0 - (-f.optical_depth(&ray.between(ray.t0, t))).exp();
            let got = times.iter().filter(|&&x| x < t).count() as f64 / trials as f64;
            let se = (expect * (1.0 - expect) / trials as f64).sqrt().max(1e-4);
            assert!(
                (got - expect).abs() < 5.0 * se,
                "t = {t}: {got} vs {expect}"
            );
        }
    }
}

/// The cells' shot noise lets little light through: over rays through a uniform random cloud
/// (optical depth ~3 across), the mean transmittance is e^{−mean τ} within 1 % (cells of eight
/// particles, before issue 24.3: 2 % more here, Jensen's inequality; 5.8 % in a 10 cm cloud of 10^7
/// grains at τ 4.5, BENCHMARKS.md).
#[test]
fn cells_add_no_transmittance() {
    let mut s = 21u64;
    let n = 200_000;
    let pos = random_points(&mut s, n);
    let w = vec![3.0 / n as f64; n]; // σ_t = 3 per unit length in the unit cube
    let f = ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, None).unwrap();
    let (mut tau, mut tr) = (0.0, 0.0);
    let rays = 4000;
    for _ in 0..rays {
        let o = [0.02 + 0.96 * lcg(&mut s), 0.02 + 0.96 * lcg(&mut s), -1.0];
        let t = f.optical_depth(&RaySegment::new(o, [0.0, 0.0, 1.0], 0.0, 3.0));
        tau += t / rays as f64;
        tr += (-t).exp() / rays as f64;
    }
    assert!((tau - 3.0).abs() < 0.1, "{tau}");
    assert!(
        (tr / (-tau).exp() - 1.0).abs() < 0.01,
        "{tr} vs {}",
        (-tau).exp()
    );
}

/// Sparse grains stay discrete, dense small-τ ones become continuous; an infinite threshold keeps all;
/// disks large against the box stay discrete (their edge share).
#[test]
fn resolvable_classes() {
    let n = 80_000;
    let pos = random_points(&mut 9, n);
    // Half the particles with R = 0.02 (many per cylinder of the unit cube's chord 2/3:
    // 4e4 π 0.02² · 2/3 ≈ 34; edge share (8/9π)·0.02·3 ≈ 0.017), half with R = 0.002 (0.3).
    let reach: Vec<f64> = (0..n)
        .map(|i| if i % 2 == 0 { 0.02 } else { 0.002 })
        .collect();
    let w: Vec<f64> = reach.iter().map(|r| PI * r * r * 1e-3).collect();
    let (keep, footprint) = resolvable(&pos, &|i| reach[i], &|i| w[i], 16.0);
    assert!((0..n).all(|i| keep[i] == (i % 2 == 1)));
    assert!(footprint.is_some());
    assert!(resolvable(&pos, &|i| reach[i], &|i| w[i], f64::INFINITY)
        .0
        .iter()
        .all(|&k| k));
    // Optically thick: the mean free path limits the cylinder (σ_t = 4e4·π·0.02²·0.5 ≈ 25 per unit).
    let w_thick: Vec<f64> = reach.iter().map(|r| PI * r * r * 0.5).collect();
    let keep = resolvable(&pos, &|i| reach[i], &|i| w_thick[i], 16.0).0;
    assert!(keep.iter().all(|&k| k));
    // Disks of R = 0.05 (edge share 0.042): 4e4 π 0.05² · 2/3 ≈ 209 per cylinder, still discrete.
    let wide: Vec<f64> = (0..n)
        .map(|i| if i % 2 == 0 { 0.05 } else { 0.002 })
        .collect();
    let keep = resolvable(&pos, &|i| wide[i], &|i| PI * wide[i] * wide[i] * 1e-3, 16.0).0;
    assert!(keep.iter().all(|&k| k));
    assert!((edge_share(0.05, [1.0; 3]) - 8.0 / (9.0 * PI) * 0.15).abs() < 1e-12);
}
/// `edge_share` against a count: grains uniform in a box, a point uniform on each one's disk normal
/// to an axis, the share of those points outside the box's two other extents, averaged over axes.
#[test]
fn edge_share_matches_a_count() {
    let (e, reach) = ([1.0, 2.0, 0.5], 0.03);
    let mut s = 17u64;
    let (mut outside, samples) = (0usize, 600_000usize);
    for k in 0..samples {
        let axis = k % 3;
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let (r, phi) = (reach * lcg(&mut s).sqrt(), 2.0 * PI * lcg(&mut s));
        let (x, y) = (e[u] * lcg(&mut s), e[v] * lcg(&mut s));
        let (x, y) = (x + r * phi.cos(), y + r * phi.sin());
        outside += usize::from(x < 0.0 || x > e[u] || y < 0.0 || y > e[v]);
    }
    let counted = outside as f64 / samples as f64;
    let formula = edge_share(reach, e);
    assert!(
        (counted / formula - 1.0).abs() < 0.03,
        "{counted} vs {formula}"
    );
}

/// A field of few classes picks from its table of each cell's distinct classes (`picking_by` each
/// class alone) with the same probabilities as from the list of its particles; one of many classes
/// keeps the list alone, unless they fall in few groups.
#[test]
fn picks_of_distinct_classes_match_the_list() {
    let mut s = 17u64;
    let n = 20_000;
    let pos = random_points(&mut s, n);
    let w: Vec<f64> = (0..n).map(|_| 1e-5 * (0.2 + lcg(&mut s))).collect();
    for classes_count in [1u32, 3, 5000] {
        let classes: Vec<u32> = (0..n)
            .map(|_| (lcg(&mut s) * classes_count as f64) as u32)
            .collect();
        let mut f = ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, Some(&classes))
            .unwrap()
            .picking_by(|k| k);
        assert_eq!(f.picks.is_some(), classes_count <= 16, "{classes_count}");
        let Some(table) = f.picks.take() else {
            continue;
        };
        let cells = f.start.len() - 1;
        for cell in (0..cells).step_by(7) {
            let (mut by_list, mut by_table) = (vec![0u32; 0], vec![0u32; 0]);
            let steps = 65_535 * 2;
            f.picks = None;
            for j in 0..steps {
                by_list.extend(f.pick(cell, (j as f64 + 0.5) / steps as f64));
            }
            f.picks = Some(table.clone());
            for j in 0..steps {
                by_table.extend(f.pick(cell, (j as f64 + 0.5) / steps as f64));
            }
            by_list.sort_unstable();
            by_table.sort_unstable();
            assert_eq!(by_list, by_table, "cell {cell}");
            f.picks = None;
        }
    }
    // Many classes in four groups: the groups are picked as the list picks them, each by a class
    // of its own.
    let classes: Vec<u32> = (0..n).map(|_| (lcg(&mut s) * 5000.0) as u32).collect();
    let group = |k: u32| (k & 0xFFFF) % 4;
    let f = ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, Some(&classes)).unwrap();
    let f = f.picking_by(|k| k);
    assert!(f.picks.is_none());
    let mut f = f.picking_by(group);
    let table = f.picks.take().expect("four groups");
    for cell in (0..f.start.len() - 1).step_by(7) {
        let steps = 65_535 * 2;
        let mut by_list: Vec<u32> = (0..steps)
            .filter_map(|j| f.pick(cell, (j as f64 + 0.5) / steps as f64))
            .map(group)
            .collect();
        f.picks = Some(table.clone());
        let mut by_table: Vec<u32> = (0..steps)
            .filter_map(|j| f.pick(cell, (j as f64 + 0.5) / steps as f64))
            .map(group)
            .collect();
        f.picks = None;
        by_list.sort_unstable();
        by_table.sort_unstable();
        assert_eq!(by_list, by_table, "cell {cell}");
    }
    // Without its list (the grains' equivalent): the same picks, the table's classes as each
    // cell's members, four bytes fewer per particle; a field without a table keeps its list.
    f.picks = Some(table);
    let picks = |f: &ContinuousField| -> Vec<Option<u32>> {
        (0..f.start.len() - 1)
            .flat_map(|c| (0..100).map(move |j| (c, (j as f64 + 0.5) / 100.0)))
            .map(|(c, u)| f.pick(c, u))
            .collect()
    };
    let (before, bytes) = (picks(&f), f.bytes());
    let members: Vec<Vec<u32>> = (0..f.start.len() - 1)
        .map(|c| f.members(c).collect())
        .collect();
    let f = f.forget_members();
    assert_eq!(picks(&f), before);
    assert_eq!(f.bytes() + 4 * n, bytes);
    assert_eq!(f.len(), n);
    for (c, m) in members.iter().enumerate() {
        let kept: Vec<u32> = f.members(c).collect();
        assert!(!kept.is_empty() || m.is_empty());
        assert!(kept.iter().all(|k| m.contains(k)), "cell {c}");
    }
    let untabled =
        ContinuousField::build(&pos, &|_| 0.001, &|i| w[i], None, Some(&classes)).unwrap();
    let bytes = untabled.bytes();
    assert_eq!(untabled.forget_members().bytes(), bytes);
}

/// Lanes of the lockstep that met a tentative collision outside the cells before their end and went on
/// one ray at a time (the tests check that they are exercised).
pub(super) static CONTINUED: std::sync::atomic::AtomicUsize =
    std::sync::atomic::AtomicUsize::new(0);

/// `inside_share`: a grain's disk of radius R across a ray in a random direction lies beyond a face at
/// distance u R from its centre by (1 − u)² / 2 of its area (Monte Carlo over directions and points of the
/// disk), and a grain far from every face keeps all of its extinction.
#[test]
fn inside_share_is_the_disk_within_the_box() {
    let mut s = 43u64;
    let samples = 200_000;
    for u in [0.0, 0.3, 0.7] {
        let mut beyond = 0usize;
        for _ in 0..samples {
            // A direction uniform on the sphere, then a point uniform on the unit disk across it.
            let z = 2.0 * lcg(&mut s) - 1.0;
            let phi = 2.0 * std::f64::consts::PI * lcg(&mut s);
            let w = [
                (1.0 - z * z).sqrt() * phi.cos(),
                (1.0 - z * z).sqrt() * phi.sin(),
                z,
            ];
            let a = if w[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            let e1 = vec3::normalise(vec3::cross(w, a)).unwrap();
            let e2 = vec3::cross(w, e1);
            let (rho, psi) = (lcg(&mut s).sqrt(), 2.0 * std::f64::consts::PI * lcg(&mut s));
            let x = rho * (psi.cos() * e1[0] + psi.sin() * e2[0]);
            beyond += (x > u) as usize;
        }
        let share = super::build::inside_share([u, 5.0, 5.0], 1.0, [0.0; 3], [10.0; 3]);
        let mc = beyond as f64 / samples as f64;
        assert!(
            (1.0 - share - mc).abs() < 0.004,
            "u {u}: {} vs {mc}",
            1.0 - share
        );
    }
    assert_eq!(
        super::build::inside_share([5.0; 3], 1.0, [0.0; 3], [10.0; 3]),
        1.0
    );
}
