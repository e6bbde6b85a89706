use super::build::TAU_OPAQUE;
use super::events::normalised_throughput;
use super::events::{key, Event, EventMap, Events, Parent, NO_EVENT};
use super::flight::Grains;
use super::lane::{at_site, site_position, PendingLane};
use super::phase::Mixture;
use super::*;
use crate::render::footprint::Camera;
use crate::render::phase_lanes::PhaseLanes;
use crate::render::storage::Storage;
use crate::rng::uniform;
use crate::space::grid::Site;
use crate::space::vec3::{deflect, normalise};
use std::f64::consts::PI;

/// A packet's phase samples side by side (`crate::render::phase_lanes`), in AVX-512 where the CPU
/// has it and in the scalar lane loop everywhere, give every lane exactly what one lane at a time
/// gives (`event_phase_sample`): direction, weights, pdf and the throughput after the bounce, bit
/// for bit. Packets of 1 to 16 lanes, one to three channels, known and unknown throughputs, draws
/// at the ends of [0, 1), samples in long directory buckets (halved before they are searched) and
/// in short ones, events with and without their own albedo, slots left over from
/// the previous packet, and an albedo scaled to 0 (every sample null).
#[test]
fn phase_lanes_match_one_lane_at_a_time() {
    if !crate::simd::lockstep_simd() {
        crate::simd::say_simd_half_not_run(
            "phase_lanes_match_one_lane_at_a_time",
            "no AVX-512 here (CPU or MOTES_SIMD): the scalar lane loop stood in for it",
        );
    }
    let mut s = 11u64;
    let mut r = || crate::test_rng::lcg(&mut s);
    let (mut long, mut short, mut alone) = (0, 0, 0);
    // The albedo scaled to 0 (every sample null), and one bin black at 500 nm (that channel neither
    // picked nor valued there).
    let media = [(medium(400), 1.0), (medium(400), 0.0)];
    let black = (medium_with_albedo(400, f64::INFINITY, [0.0, 0.7]), 1.0);
    for (m, scale) in media.iter().chain([&black]) {
        m.set_albedo_scale(*scale).unwrap();
        for lam in [vec![500.0, 600.0], vec![600.0, 500.0, 500.0], vec![500.0]] {
            let ls = m.brackets(&lam);
            let first = m.bins[0].phase[ls[0].0].sampling_view();
            let mut side = PhaseLanes::new(lam.len(), first);
            for round in 0..60 {
                let n = 1 + round % PACKET_LANES;
                let mut lanes = Vec::new();
                for k in 0..n {
                    let mut site = Site::default();
                    site.push((r() * 400.0) as u32 % 400);
                    let t_in = if r() < 0.3 {
                        [0.0; MAX_CHANNELS]
                    } else {
                        normalised_throughput((0..lam.len()).map(|_| r()))
                    };
                    let mut e = Event {
                        site,
                        t_in,
                        t_out: t_in,
                        depth: 1,
                        ..NO_EVENT
                    };
                    if k % 3 == 1 {
                        // The event's own albedo (remembered at these wavelengths).
                        e.albedo = [0.9, 0.7, 0.5, 0.3];
                        e.albedo_nm = lam[0] as f32;
                    }
                    let w_in = normalise([r() - 0.5, r() - 0.5, r() - 0.5]).unwrap();
                    let edge = |x: f64| match k % 5 {
                        0 => 0.0,
                        1 => 1.0 - f64::EPSILON,
                        _ => x,
                    };
                    // Now and then a draw that is not a number: left to the caller.
                    let nan = (round + k) % 13 == 12;
                    let lane = PhaseSampleLane {
                        p: [0.0; 3],
                        wi: [0.0; 3],
                        u1: if nan && k % 2 == 0 {
                            f64::NAN
                        } else {
                            edge(r())
                        },
                        u2: [
                            if nan && k % 2 == 1 {
                                f64::NAN
                            } else {
                                edge(r())
                            },
                            r(),
                        ],
                    };
                    assert!(m.fill_phase_lane(&e, &lane, &lam, &ls, &mut side, k));
                    lanes.push((e, w_in, lane));
                }
                (side.n, side.channels) = (n, lam.len());
                for force_scalar in [true, false] {
                    let mut got = side;
                    // SAFETY: the tables are `m`'s, alive throughout.
                    unsafe { got.sample(force_scalar) };
                    for (k, (e, w_in, lane)) in lanes.iter().enumerate() {
                        let (want, t_want) = m.event_phase_sample(e, *w_in, lane, &lam, &ls, true);
                        let nan = lane.u1.is_nan() || lane.u2[0].is_nan();
                        assert_eq!(got.alone[k] != 0, nan, "lane {k}: left alone iff NaN");
                        assert_eq!(side.is_alone(k), nan, "lane {k}");
                        if nan {
                            alone += 1;
                            continue;
                        }
                        // SAFETY: as above.
                        if unsafe { side.in_long_bucket(k) } {
                            long += 1;
                        } else {
                            short += 1;
                        }
                        if got.ok[k] == 0 {
                            assert!(!(want.2 > 0.0), "{lam:?} lane {k}: null, want {want:?}");
                            continue;
                        }
                        let at = format!("{lam:?} lane {k} of {n}, scalar {force_scalar}");
                        let bits = |v: [f64; 3]| v.map(f64::to_bits);
                        assert_eq!(got.pdf[k].to_bits(), want.2.to_bits(), "{at}");
                        let dir = deflect(*w_in, got.mu[k], lane.u2[1]);
                        assert_eq!(bits(dir), bits(want.0), "{at}");
                        for c in 0..lam.len() {
                            let w = (got.weight[c][k].to_bits(), want.1[c].to_bits());
                            assert_eq!(w.0, w.1, "{at}: channel {c}");
                            let t = (got.t_out[c][k] as f32).to_bits();
                            assert_eq!(t, t_want.unwrap()[c].to_bits(), "{at}");
                        }
                    }
                }
            }
        }
    }
    assert!(
        long > 100 && short > 1000 && alone > 20,
        "long {long}, short {short}, alone {alone}"
    );
}

/// Each disk removes exactly C from a beam: π R² (1 − e^{−τ}) = C, whatever r_c (issue 9.0), and
/// τ ≤ τ_max; with r_c = 0 and Q = 2 the paper's τ = C / (π R²) would be 2 (43 % of C removed).
#[test]
fn disks_remove_their_cross_section() {
    for &(r, q, rc, tmax) in &[
        (1.0, 2.0, 0.0, DEFAULT_TAU_MAX),
        (1.0, 2.0, 0.0, f64::INFINITY),
        (1.0, 1.0, 0.0, f64::INFINITY),
        (1.0, 2.0, 10.0, 0.1),
        (0.5, 2.2, 0.1, 0.05),
    ] {
        let c = q * PI * r * r;
        let (reach, tau) = particle_disk(r, c, rc, tmax);
        assert!(reach >= rc + r);
        assert!(tau <= tmax.min(TAU_OPAQUE) + 1e-12, "{tau}");
        let removed = PI * reach * reach * (1.0 - (-tau).exp());
        assert!(
            (removed / c - 1.0).abs() < 1e-9,
            "{r} {q} {rc} {tmax}: {removed} vs {c}"
        );
    }
}

/// The channel throughput carried by events: sampling channel c ∝ t_c keeps Σ_c t_c f_c / q at 1
/// for a non-absorbing medium, so per-channel path weights stay bounded over many bounces.
#[test]
fn channel_weights_stay_bounded_along_a_chain() {
    let m = medium(4000);
    let mut o = [0.5f32, 0.5, -0.2];
    let mut d = [0.0f32, 0.0, 1.0];
    let mut throughput = [1.0f64; 2];
    let mut k = 0u64;
    let mut bounces = 0;
    for _ in 0..20000 {
        let r = m.sample_sites(&[o], &[d], &[f64::INFINITY], &[true]);
        let Some(t) = r[0].t else {
            o = [0.5, 0.5, -0.2];
            d = [0.0, 0.0, 1.0];
            continue;
        };
        let p = [0, 1, 2].map(|a| o[a] + t as f32 * d[a]);
        let a = m.commit_events(&[p], &[true], &[500.0, 600.0], 2).unwrap();
        k += 1;
        let u = |s: u64| uniform(11, k, s);
        let lane = PhaseSampleLane {
            p,
            wi: d.map(|x| -x),
            u1: u(0),
            u2: [u(1), u(2)],
        };
        let (wo, w, pdf) = m.phase_sample(&[lane], &[500.0, 600.0], 2);
        if pdf[0] <= 0.0 {
            continue;
        }
        for c in 0..2 {
            throughput[c] *= a[c] * w[c];
        }
        // Σ_c t_c is what the throughput-proportional choice preserves (up to albedo and ε).
        assert!(
            throughput.iter().all(|x| x.is_finite() && *x < 50.0),
            "{throughput:?}"
        );
        o = p;
        d = wo[0].map(|x| x as f32);
        bounces += 1;
    }
    assert!(bounces > 1000);
}

fn table(g: f64) -> PhaseTable {
    // Henyey–Greenstein on a fine grid.
    let theta: Vec<f64> = (0..2001).map(|i| PI * i as f64 / 2000.0).collect();
    let f: Vec<f64> = theta
        .iter()
        .map(|t| (1.0 - g * g) / (4.0 * PI * (1.0 + g * g - 2.0 * g * t.cos()).powf(1.5)))
        .collect();
    PhaseTable::new(&theta, &f).unwrap()
}

fn medium(n: usize) -> DiscreteMedium {
    medium_with(n, f64::INFINITY)
}

/// The test medium with a `continuous_count` (1: its one size class, 1.7 particles per cylinder,
/// is continuous).
fn medium_with(n: usize, continuous_count: f64) -> DiscreteMedium {
    medium_with_albedo(n, continuous_count, [0.5, 0.7])
}

/// [`medium_with`], its second bin's albedo at 500 and 600 nm given.
fn medium_with_albedo(n: usize, continuous_count: f64, albedo: [f64; 2]) -> DiscreteMedium {
    medium_stored(n, continuous_count, albedo, Storage::Full)
}

/// [`medium_with_albedo`] with its particles kept as `storage` says.
fn medium_stored(
    n: usize,
    continuous_count: f64,
    albedo: [f64; 2],
    storage: Storage,
) -> DiscreteMedium {
    let mut s = 3u64;
    let mut r = || crate::test_rng::lcg(&mut s);
    let pos: Vec<[f64; 3]> = (0..n).map(|_| [r(), r(), r()]).collect();
    let rad: Vec<f64> = (0..n).map(|_| 0.002 + 0.004 * r()).collect();
    let c: Vec<f64> = rad.iter().map(|x| 2.0 * PI * x * x).collect();
    let bins = vec![
        BinOptics {
            albedo: vec![1.0, 0.9],
            phase: vec![table(0.3), table(0.5)],
            mueller: Vec::new(),
        },
        BinOptics {
            albedo: albedo.to_vec(),
            phase: vec![table(-0.2), table(0.8)],
            mueller: Vec::new(),
        },
    ];
    let bin: Vec<u32> = (0..n).map(|i| (i % 2) as u32).collect();
    let settings = MediumSettings {
        query_radius: 0.01,
        tau_max: DEFAULT_TAU_MAX,
        cells_per_particle: 1.0,
        continuous_count,
        seed: 7,
        storage,
        ..MediumSettings::default()
    };
    DiscreteMedium::build(
        &pos,
        &rad,
        1.0,
        &|i| c[i],
        &bin,
        bins,
        vec![500.0, 600.0],
        &settings,
    )
    .unwrap()
}

/// Runs `check(medium, continuous_count)` on the test medium of 4000 particles kept discrete
/// (an infinite `continuous_count`) and as a continuous field (1).
fn discrete_and_continuous(check: impl Fn(&DiscreteMedium, f64)) {
    for continuous_count in [f64::INFINITY, 1.0] {
        check(&medium_with(4000, continuous_count), continuous_count);
    }
}

/// Sites are sampled with the exact escape probability exp(−τ) (binomial 5σ bound), and the
/// walked optical depth before a site never exceeds the segment's; the same with the particles
/// as a continuous field.
#[test]
fn site_escape_probability() {
    discrete_and_continuous(|m, continuous_count| {
        assert_eq!(m.continuous_len() > 0, continuous_count.is_finite());
        let lanes = 40000;
        let o = vec![[0.5f32, 0.5, -0.2]; lanes];
        let d = vec![[0.0f32, 0.0, 1.0]; lanes];
        let tm = vec![1.4; lanes];
        let ray = RaySegment::new([0.5, 0.5, -0.2], [0.0, 0.0, 1.0], 0.0, 1.4);
        let tau = [m.optical_depth(&ray)];
        let res = m.sample_sites(&o, &d, &tm, &vec![true; lanes]);
        let escaped = res.iter().filter(|r| r.t.is_none()).count();
        assert!(tau[0] > 0.2, "{}", tau[0]);
        crate::test_rng::assert_escape_fraction(escaped, lanes, (-tau[0]).exp());
        for r in &res {
            assert!(r.tau_before <= tau[0] + 1e-6);
        }
    });
}

/// Eq. 24 at points: the mean of σ_s(p) over random interior points is the bulk Σ C_s / V (6σ),
/// and sampling the local mixture returns the pdf that evaluation gives (mean of Q_c / σ_s,c).
#[test]
fn local_scattering_is_unbiased_and_consistent() {
    discrete_and_continuous(|m, continuous_count| {
        let mut s = 99u64;
        let mut r = || crate::test_rng::lcg(&mut s);
        // Discrete: interior points, away from the faces of the particles' unit box (balls
        // stick out). Continuous: the whole box, because a sub-box's mean differs from the
        // box's by the cells' own fluctuation (~8 particles per cell: 35 % per cell, ~2 % over
        // a sub-box).
        let (a, w) = if continuous_count.is_finite() {
            (0.0, 1.0)
        } else {
            (0.1, 0.8)
        };
        let pts: Vec<[f64; 3]> = (0..40000)
            .map(|_| [a + w * r(), a + w * r(), a + w * r()])
            .collect();
        let mu = vec![0.3; pts.len()];
        let (sigma, q) = m.local_scattering(&pts, &mu, &[500.0], 1);
        let mean = sigma.iter().sum::<f64>() / sigma.len() as f64;
        let var = sigma.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (sigma.len() - 1) as f64;
        // bulk: Σ_i C_t,i a_i / V over the unit box (albedo 1.0 / 0.5 by bin at 500 nm)
        let bulk: f64 = (0..m.len())
            .map(|i| m.optics.c_ext(i as u32) * m.bins[m.optics.bin(i as u32)].albedo[0])
            .sum::<f64>();
        let se = (var / sigma.len() as f64).sqrt();
        assert!(
            (mean - bulk).abs() < 6.0 * se,
            "mean σ_s {mean} vs bulk {bulk} (se {se})"
        );
        assert!(q
            .iter()
            .zip(&sigma)
            .all(|(a, b)| *a >= 0.0 && (*b > 0.0 || *a == 0.0)));
        let n = 2000;
        let w_in = vec![[0.0, 0.0, 1.0]; n];
        let u1: Vec<f64> = (0..n).map(|_| r()).collect();
        let u2: Vec<[f64; 2]> = (0..n).map(|_| [r(), r()]).collect();
        let (wo, w, pdf) = m.sample_local(&pts[..n], &w_in, &[500.0, 600.0], 2, &u1, &u2);
        for i in 0..n {
            if pdf[i] == 0.0 {
                continue;
            }
            let (sg, qq) = m.local_scattering(&pts[i..i + 1], &[wo[i][2]], &[500.0, 600.0], 2);
            let expect = (qq[0] / sg[0] + qq[1] / sg[1]) / 2.0;
            assert!(
                (pdf[i] - expect).abs() < 1e-9 * expect.max(1.0),
                "{} {}",
                pdf[i],
                expect
            );
            assert!((w[2 * i] * pdf[i] - qq[0] / sg[0]).abs() < 1e-9 * expect.max(1.0));
        }
    });
}

/// A ray leaving an event at or past the grain depth sees the grains' continuous equivalent where its
/// pixel footprint holds many grains (a camera far away with wide pixels): it escapes with
/// probability exp(−τ of that field) and interacts anywhere along the ray, not only at grains; below
/// the grain depth, without cameras (the footprint unknown), with sharp pixels, or with an infinite
/// `continuous_count`, it walks the grains.
#[test]
fn rays_past_the_grain_depth_see_the_continuous_equivalent() {
    for continuous_count in [16.0, f64::INFINITY] {
        let m = medium_with(4000, continuous_count);
        assert_eq!(m.continuous_len(), 0); // every class discrete either way
        let (o, d) = ([[0.5f32, 0.5, -0.2]], [[0.0f32, 0.0, 1.0]]);
        let t = (0..200)
            .find_map(|_| m.sample_sites(&o, &d, &[f64::INFINITY], &[true])[0].t)
            .expect("an event");
        let p = [0.5f32, 0.5, (-0.2 + t) as f32];
        m.commit_events(&[p], &[true], &[500.0, 600.0], 2).unwrap();
        let lanes = 20000;
        let sites_from_event = |depth: u32| {
            m.set_grain_depth(depth).unwrap();
            let r = m.sample_sites(
                &vec![p; lanes],
                &vec![d[0]; lanes],
                &vec![1.0; lanes],
                &vec![false; lanes],
            );
            r.iter().map(|x| x.t).collect::<Vec<_>>()
        };
        let distinct = |ts: &[Option<f64>]| {
            let mut v: Vec<u64> = ts.iter().flatten().map(|t| t.to_bits()).collect();
            v.sort_unstable();
            v.dedup();
            v.len()
        };
        let walked = sites_from_event(2);
        assert!(distinct(&walked) < 100, "{}", distinct(&walked)); // grains only
        let no_camera = sites_from_event(1);
        assert!(distinct(&no_camera) < 100, "{}", distinct(&no_camera));
        let camera = |pixel_angle: f64| View {
            cameras: vec![Camera::new([30.0, 0.5, -40.0], pixel_angle, 0.0).unwrap()],
            lights: Some(vec![]),
            diffuse_surfaces: false,
            samples_per_pixel: 0.0,
        };
        m.set_view(camera(1e-7));
        let sharp = sites_from_event(1);
        assert!(distinct(&sharp) < 100, "{}", distinct(&sharp));
        m.set_view(camera(0.05));
        let seen = sites_from_event(1);
        match &m.grains_field {
            Some(f) => {
                assert!(distinct(&seen) > 1000, "{}", distinct(&seen));
                let ray = RaySegment::new(p.map(|x| x as f64), [0.0, 0.0, 1.0], 0.0, 1.0);
                let escaped = seen.iter().filter(|t| t.is_none()).count();
                let tau = f.optical_depth(&ray);
                assert!(tau > 0.1, "{tau}");
                crate::test_rng::assert_escape_fraction(escaped, lanes, (-tau).exp());
            }
            None => assert!(distinct(&seen) < 100, "{}", distinct(&seen)), // exact: no field at all
        }
    }
}

/// A ray along +z through the test medium whose free flight (lane 1 of a packet) meets a site in
/// the cube's lower half (rays from it cross much of the cube): the first of a row of origins
/// (which one depends on the free flights' random numbers).
fn ray_with_site(m: &DiscreteMedium, lambda: &[f64]) -> ([f32; 3], [f32; 3]) {
    let d = [0.0f32, 0.0, 1.0];
    (0..400)
        .map(|k| [0.3 + 0.001 * k as f32, 0.5, -0.2])
        .find(|&o| {
            let mut t = [None; 2];
            m.packet_free_flights(&[None, Some((o, d, 10.0))], lambda, 2, &mut t);
            t[1].is_some_and(|t| t < 0.7)
        })
        .map(|o| (o, d))
        .expect("a ray that meets a site")
}

/// A packet phase sample with lane 1 active (two channels): directions, weights and pdfs, every
/// output first NaN so that each must be written.
fn sample_lane_1(
    m: &DiscreteMedium,
    lane: PhaseSampleLane,
    lambda: &[f64],
    evaluated_next: bool,
) -> ([[f64; 3]; 2], [f64; 4], [f64; 2]) {
    let (mut wo, mut w, mut pdf) = ([[f64::NAN; 3]; 2], [f64::NAN; 4], [f64::NAN; 2]);
    m.packet_phase_sample(
        &[None, Some(lane)],
        lambda,
        2,
        &mut wo,
        &mut w,
        &mut pdf,
        evaluated_next,
    );
    (wo, w, pdf)
}

/// Lane 1's pending site after a free flight along +z ([`ray_with_site`]): the ray's direction and
/// where the renderer puts the site.
fn pending_site(m: &DiscreteMedium, lambda: &[f64]) -> ([f32; 3], [f32; 3]) {
    let (o, d) = ray_with_site(m, lambda);
    let mut t = [None; 2];
    m.packet_free_flights(&[None, Some((o, d, 10.0))], lambda, 2, &mut t);
    (d, site_position(o, d, t[1].expect("a site")))
}

/// A packet lane's site becomes its event where the lane's next call starts at it (the position as
/// the renderer computes it, o + t d in float32): the map holds it, the lane's own copy carries the
/// phase sample's throughput, and its phase function's values and weights carry the site's
/// albedo. A site no call starts at (a shadow ray's) is never remembered.
#[test]
fn a_lanes_site_is_settled_where_its_path_goes_on() {
    let m = medium(4000);
    let lambda = [500.0, 600.0];
    let (o, d) = ray_with_site(&m, &lambda);
    for _ in 0..3 {
        let mut t = [None; 2];
        m.packet_free_flights(&[None, Some((o, d, 10.0))], &lambda, 2, &mut t);
        let t = t[1].expect("a site") as f32;
        let p = [0, 1, 2].map(|a| d[a].mul_add(t, o[a]));
        let lane = PhaseSampleLane {
            p,
            wi: d,
            u1: 0.3,
            u2: [0.2, 0.7],
        };
        let (wo, w, pdf) = sample_lane_1(&m, lane, &lambda, false);
        assert!(pdf[1] > 0.0);
        let event = m.with_packet_state(|st| {
            let (at, e) = st.recent[1].expect("lane 1's event");
            assert_eq!(at, key(p));
            let mapped = st.events.get(&at).expect("in the map");
            assert_eq!(e.t_in, mapped.t_in);
            assert!(e.t_out.iter().any(|&x| x > 0.0));
            assert_eq!(st.lane(1).event(&at).map(|e| e.t_out), Some(e.t_out));
            assert!(st.recent[0].is_none());
            e
        });
        // The weights are the plain sample's times the albedo.
        let mut map = EventMap::new(4);
        map.insert(key(p), event);
        let ls = m.brackets(&lambda);
        let ((wo_plain, w_plain, pdf_plain), _) =
            m.lane_phase_sample(&map, &lane, &lambda, &ls, false);
        assert_eq!(wo[1], wo_plain);
        assert!((pdf[1] / pdf_plain - 1.0).abs() < 1e-12);
        let albedo = [0, 1].map(|c| m.site_albedo(&event.site, m.bracket(lambda[c])));
        // Every particle of the test medium has an albedo below 1 in some channel.
        assert!(albedo.iter().any(|&a| a < 1.0), "{albedo:?}");
        for c in 0..2 {
            let a = albedo[c];
            assert!(a > 0.0 && a <= 1.0, "{a}");
            assert!(
                (w[2 + c] / (w_plain[c] * a) - 1.0).abs() < 1e-6,
                "{w:?} {w_plain:?} {a}"
            );
        }
        // A shadow ray from the event (the first of some directions that meets a grain): its site
        // is left pending, then replaced.
        let q = (0..200)
            .find_map(|k| {
                let a = 0.1 * k as f32;
                let ds = [a.sin() * 0.6, a.cos() * 0.6, 0.8];
                let mut s = [None; 2];
                m.packet_free_flights(&[None, Some((p, ds, 10.0))], &lambda, 2, &mut s);
                let ts = s[1]? as f32;
                Some([0, 1, 2].map(|a| ds[a].mul_add(ts, p[a])))
            })
            .unwrap_or_else(|| panic!("a shadow ray that meets a grain from {p:?} (o {o:?})"));
        m.with_packet_state(|st| assert!(st.pending[1].site.is_some()));
        let mut s = [None; 2];
        m.packet_free_flights(&[None, Some((o, d, 10.0))], &lambda, 2, &mut s);
        m.with_packet_state(|st| {
            assert!(st.events.get(&key(q)).is_none());
            assert_eq!(st.recent[1].map(|r| r.0), Some(key(p)));
        });
    }
}

/// Positions a few ulps from a lane's site are its site; others are not.
#[test]
fn sites_are_found_within_a_few_ulps() {
    let at = [0.25f32, -3.0, 1e-9];
    assert!(at_site(at, at));
    let up = |x: f32, n: i32| f32::from_bits((x.to_bits() as i32 + n) as u32);
    assert!(at_site([up(0.25, 4), up(-3.0, -4), up(1e-9, 3)], at));
    assert!(!at_site([up(0.25, 9), -3.0, 1e-9], at)); // |x| ε is one to two ulps
    assert!(!at_site([0.25, up(-3.0, 9), 1e-9], at));
    assert!(!at_site([0.2501, -3.0, 1e-9], at));
    assert!(!at_site([0.25, -3.0, 2e-9], at));
    assert!(!at_site([f32::NAN, -3.0, 1e-9], at));
    // −0 and +0: one position, one key.
    assert!(at_site([0.0, -3.0, 1e-9], [-0.0, -3.0, 1e-9]));
    assert_eq!(key([-0.0, 1.0, 2.0]), key([0.0, 1.0, 2.0]));
}

/// A lane inactive in a packet's free flights keeps the site of its own last one: its path has
/// not moved on, and its phase function finds the event there.
#[test]
fn inactive_lanes_keep_their_site() {
    let m = medium(4000);
    let lambda = [500.0, 600.0];
    let (o, d) = ray_with_site(&m, &lambda);
    let mut t = [None; 2];
    m.packet_free_flights(&[None, Some((o, d, 10.0))], &lambda, 2, &mut t);
    let p = site_position(o, d, t[1].expect("a site"));
    // Another lane's free flight (lane 1 inactive), as a shadow ray of lane 0's path.
    let mut t0 = [None; 2];
    m.packet_free_flights(
        &[Some((o, [0.0, 1.0, 0.0], 10.0)), None],
        &lambda,
        2,
        &mut t0,
    );
    assert_eq!(t0[1], None);
    let lane = PhaseEvalLane {
        p,
        wi: d.map(|x| -x),
        wo: [0.0, 0.6, 0.8],
    };
    let (mut v, mut pdf) = ([0.0; 4], [0.0; 2]);
    m.packet_phase_eval(&[None, Some(lane)], &lambda, 2, &mut v, &mut pdf);
    assert!(pdf[1] > 0.0);
    m.with_packet_state(|st| assert_eq!(st.recent[1].map(|r| r.0), Some(key(p))));
}

/// A phase evaluation from a lane's last free-flight origin towards its direction, where that flight
/// ended at a site inside the medium's enclosure, is zero (next-event estimation multiplies it by
/// the light the blocked shadow ray does not see), once; any other is computed: no enclosure, an
/// enclosure that does not hold the site, another direction, a second evaluation.
#[test]
fn an_evaluation_behind_a_blocked_shadow_ray_is_zero_inside_the_enclosure() {
    use crate::render::enclosure::{Enclosure, Region};
    let m = medium(4000);
    let lambda = [500.0, 600.0];
    let (d, p) = pending_site(&m, &lambda);
    // A shadow ray from the event that meets a site (the first of some directions; its flight
    // settles the event). The same ray always meets the same site (its numbers come from the ray).
    let flight = |m: &DiscreteMedium, ds: [f32; 3]| {
        let mut s = [None; 2];
        m.packet_free_flights(&[None, Some((p, ds, 10.0))], &lambda, 2, &mut s);
        s[1]
    };
    let ds = (0..200)
        .map(|k| {
            let a = 0.1 * k as f32;
            [a.sin() * 0.6, a.cos() * 0.6, 0.8]
        })
        .find(|&ds| flight(&m, ds).is_some_and(|t| t > 1e-3))
        .expect("a shadow ray that meets a grain");
    let eval = |m: &DiscreteMedium, wo: [f32; 3]| {
        let lane = PhaseEvalLane {
            p,
            wi: d.map(|x| -x),
            wo,
        };
        let (mut v, mut pdf) = ([0.0; 4], [0.0; 2]);
        m.packet_phase_eval(&[None, Some(lane)], &lambda, 2, &mut v, &mut pdf);
        (v[2] + v[3], pdf[1])
    };
    let computed = eval(&m, ds);
    assert!(computed.0 > 0.0 && computed.1 > 0.0, "{computed:?}");
    m.set_enclosure(Enclosure {
        regions: vec![Region::ball([0.5; 3], 10.0).unwrap()],
    });
    flight(&m, ds);
    assert_eq!(eval(&m, ds), (0.0, 0.0));
    assert_eq!(eval(&m, ds), computed, "one evaluation per blocked flight");
    flight(&m, ds);
    let other = [ds[0], ds[1] + 2e-3, ds[2]];
    assert!(eval(&m, other).0 > 0.0, "another direction");
    // A region that holds the event but not the site.
    m.set_enclosure(Enclosure {
        regions: vec![Region::ball(p.map(|x| x as f64), 5e-4).unwrap()],
    });
    flight(&m, ds);
    assert_eq!(eval(&m, ds), computed);
    m.set_enclosure(Enclosure::default());
    flight(&m, ds);
    assert_eq!(eval(&m, ds), computed);
}

/// A site that scatters nothing (every albedo scaled to 0) gives a phase sample of zero weight and
/// pdf 1, not pdf 0: the integrator ends the path there (with pdf 0 it would leave the path on the
/// ray Mitsuba cut at the site).
#[test]
fn black_grains_end_the_path_with_a_zero_weight() {
    let m = medium(4000);
    let lambda = [500.0, 600.0];
    m.set_albedo_scale(0.0).unwrap();
    let (d, p) = pending_site(&m, &lambda);
    let lane = PhaseSampleLane {
        p,
        wi: d,
        u1: 0.3,
        u2: [0.2, 0.7],
    };
    let (wo, w, pdf) = sample_lane_1(&m, lane, &lambda, true);
    assert_eq!(pdf[1], 1.0);
    assert_eq!(&w[2..], &[0.0, 0.0]);
    let n: f64 = wo[1].iter().map(|x| x * x).sum();
    assert!((n - 1.0).abs() < 1e-12, "{:?}", wo[1]);
    // The spectral variants' second call, at the sampled direction, agrees.
    let e = PhaseEvalLane {
        p,
        wi: d,
        wo: wo[1].map(|x| x as f32),
    };
    let (mut v, mut pe) = ([1.0; 4], [0.0; 2]);
    m.packet_phase_eval(&[None, Some(e)], &lambda, 2, &mut v, &mut pe);
    assert_eq!((&v[2..], pe[1]), (&[0.0, 0.0][..], 1.0));
}

/// Events whose rays see the grains' continuous equivalent live beside their lane only (they
/// skip no particles: the map is the record of those that do), and the lane's next free flight
/// from one sees the field; a pending site a few ulps from the lane's event (a shadow ray's) does
/// not replace it.
#[test]
fn field_events_live_beside_their_lane() {
    let m = medium_with(20000, 1.0);
    assert!(m
        .grains_field_from(&Event {
            depth: 1,
            ..NO_EVENT
        })
        .is_some());
    let (o, d) = ([0.5f32, 0.5, -0.2], [0.0f32, 0.0, 1.0]);
    let lambda = [500.0, 600.0];
    let mut t = [None; 1];
    m.packet_free_flights(&[Some((o, d, 10.0))], &lambda, 2, &mut t);
    let p = site_position(o, d, t[0].expect("a site"));
    let next = |m: &DiscreteMedium| {
        let mut t = [None; 1];
        m.packet_free_flights(&[Some((p, [0.6, 0.0, 0.8], 10.0))], &lambda, 2, &mut t);
        t[0]
    };
    next(&m);
    m.with_packet_state(|st| {
        let (k, e) = st.recent[0].expect("the lane's event");
        assert_eq!(k, key(p));
        assert_eq!(e.depth, 1);
        assert!(st.events.get(&k).is_none(), "not in the map");
        // A pending site an ulp from the event.
        let near = [p[0], p[1], f32::from_bits(p[2].to_bits() + 1)];
        st.pending[0] = PendingLane {
            site: Some(Site::default()),
            parent: Parent::default(),
            at: near,
        };
    });
    let lane = PhaseEvalLane {
        p,
        wi: d.map(|x| -x),
        wo: [0.0, 0.6, 0.8],
    };
    let (mut v, mut pdf) = ([0.0; 2], [0.0; 1]);
    m.packet_phase_eval(&[Some(lane)], &lambda, 2, &mut v, &mut pdf);
    assert!(pdf[0] > 0.0);
    m.with_packet_state(|st| {
        let (k, e) = st.recent[0].expect("the lane's event");
        assert_eq!((k, e.depth), (key(p), 1));
        assert!(st.pending[0].site.is_some(), "left pending");
    });
}

/// One particle's mixture (the fast path: its bin's tables, located once) gives what the general
/// mixture of the same particle twice gives, in every channel.
#[test]
fn one_particle_mixtures_equal_the_general_mixture() {
    let m = medium(4000);
    let ls: Vec<_> = [480.0, 550.0, 600.0, 700.0].map(|l| m.bracket(l)).to_vec();
    let pi = [0.1, 0.2, 0.3, 0.4];
    for j in [0u32, 1, 17, 3999] {
        for k in 0..=200 {
            let mu = -1.0 + 2.0 * k as f64 / 200.0;
            let (mut one, mut two) = ([0.0; 4], [0.0; 4]);
            let (single, double) = ([j], [j, j]);
            let mix = |members| Mixture {
                members,
                scale: |j| m.optics.tau(j),
                ls: &ls,
                pi: &pi,
            };
            let p1 = m.mixture_phase(&mix(&single), mu, &mut one);
            let p2 = m.mixture_phase(&mix(&double), mu, &mut two);
            assert!((p1 - p2).abs() <= 1e-12 * p2, "{p1} vs {p2}");
            for c in 0..4 {
                assert!(
                    (one[c] - two[c]).abs() <= 1e-12 * two[c],
                    "{one:?} vs {two:?}"
                );
            }
        }
    }
}

/// A packet's rays that start at no event and walk the grains together as a beam (a pixel's camera
/// rays in compact storage's centre cells) find the sites each finds alone, also beside lanes that
/// start at an event and inactive lanes.
#[test]
fn packets_walked_as_beams_find_each_rays_own_site() {
    let mut s = 41u64;
    let mut r = || crate::test_rng::lcg(&mut s);
    let n = 70_000; // compact storage's centre cells (from 2^16 discrete grains)
    let pos: Vec<[f64; 3]> = (0..n).map(|_| [r(), r(), r()]).collect();
    let rad: Vec<f64> = (0..n).map(|_| 0.002 + 0.0015 * r()).collect();
    let c: Vec<f64> = rad.iter().map(|x| 2.0 * PI * x * x).collect();
    let bins = vec![BinOptics {
        albedo: vec![0.9, 0.8],
        phase: vec![table(0.3), table(0.5)],
        mueller: Vec::new(),
    }];
    let settings = MediumSettings {
        query_radius: 0.004,
        tau_max: DEFAULT_TAU_MAX,
        cells_per_particle: 1.0,
        continuous_count: f64::INFINITY,
        seed: 7,
        storage: Storage::Compact,
        ..MediumSettings::default()
    };
    let m = DiscreteMedium::build(
        &pos,
        &rad,
        1.0,
        &|i| c[i],
        &vec![0; n],
        bins,
        vec![500.0, 600.0],
        &settings,
    )
    .unwrap();
    let Some(Grains::Stored(g)) = &m.grid else {
        panic!("stored grains")
    };
    // An event of this thread's packets for one lane to start at (it skips its particles: no beam
    // for it).
    let (o, d) = ([0.5f32, 0.5, -0.2], [0.0f32, 0.0, 1.0]);
    let mut first = [None];
    m.packet_free_flights(&[Some((o, d, 10.0))], &[500.0, 600.0], 2, &mut first);
    let event = [0.5f32, 0.5, -0.2 + first[0].expect("a site") as f32];
    m.packet_settle(&[Some(event)], &[500.0, 600.0], 2);
    assert!(m.with_packet_state(|st| st.events.get(&key(event)).is_some()));
    let (mut beams, mut sites) = (0, 0);
    for k in 0..60 {
        let eye = [0.2 + 0.6 * r(), 0.2 + 0.6 * r(), -2.0];
        let aim = [0.2 + 0.6 * r(), 0.2 + 0.6 * r(), 0.5];
        let rays: Vec<Option<PacketRay>> = (0..PACKET_LANES)
            .map(|i| {
                if i == 3 && k % 2 == 0 {
                    return None;
                }
                if i == 5 && k % 3 == 0 {
                    return Some((event, [0.1, 0.0, 0.995], 5.0));
                }
                let a = aim.map(|x| x + 0.003 * (r() - 0.5));
                let d = [0, 1, 2].map(|j| a[j] - eye[j]);
                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                Some((eye.map(|x| x as f32), d.map(|x| (x / l) as f32), 10.0f32))
            })
            .collect();
        let mut together = [None; PACKET_LANES];
        m.packet_free_flights(&rays, &[500.0, 600.0], 2, &mut together);
        for (i, ray) in rays.iter().enumerate() {
            let mut alone = [None];
            m.packet_free_flights(&[*ray], &[500.0, 600.0], 2, &mut alone);
            assert_eq!(together[i], alone[0], "packet {k}, lane {i}");
            sites += alone[0].is_some() as usize;
        }
        let segs: Vec<RaySegment> = rays
            .iter()
            .flatten()
            .filter(|r| r.0 != event)
            .map(|&(o, d, t)| {
                RaySegment::new(o.map(|x| x as f64), d.map(|x| x as f64), 0.0, t as f64)
            })
            .collect();
        let mut out = vec![(None, 0.0); segs.len()];
        beams += g.sample_sites_beam(&segs, &vec![0.5; segs.len()], m.coincide, &mut out) as usize;
    }
    assert!(beams > 50 && sites > 300, "{beams} beams, {sites} sites");
}

/// After an event is committed, a ray starting at its position skips the event's particles; the
/// phase function of the event samples what it evaluates (pdf = mean of channel values).
#[test]
fn events_exclude_and_phase_is_consistent() {
    let m = medium(4000);
    let o = [[0.5f32, 0.5, -0.2]];
    let d = [[0.0f32, 0.0, 1.0]];
    let mut site = None;
    for _ in 0..100 {
        let r = m.sample_sites(&o, &d, &[f64::INFINITY], &[true]);
        if let Some(t) = r[0].t {
            site = Some(t);
            break;
        }
    }
    let t = site.expect("an event");
    let p = [0.5f32, 0.5, (-0.2 + t) as f32];
    let alb = m.commit_events(&[p], &[true], &[500.0, 600.0], 2).unwrap();
    assert!(alb.iter().all(|a| (0.0..=1.0).contains(a)));
    let s = m.event_at(p).unwrap();
    assert!(s.len >= 1);
    // without the map entry the phase function finds the site from the geometry
    assert_eq!(
        m.site_near(p, [0.0, 0.0, 1.0])
            .map(|x| x.members().to_vec()),
        Some(s.members().to_vec())
    );
    // an event of a lane not marked `remember` (a shadow ray) is not remembered
    let mut shadow_hit = None;
    for _ in 0..200 {
        if let Some(t) = m.sample_sites(
            &[[0.5f32, 0.5, -0.2]],
            &[[0.0f32, 0.0, 1.0]],
            &[1.0],
            &[false],
        )[0]
        .t
        {
            shadow_hit = Some(t);
            break;
        }
    }
    let q = [0.5f32, 0.5, (-0.2 + shadow_hit.unwrap()) as f32];
    if q != p {
        m.commit_events(&[q], &[true], &[500.0, 600.0], 2).unwrap();
        assert!(m.event_at(q).is_none());
    }
    let wi = [0.0, 0.0, -1.0];
    let lanes: Vec<PhaseSampleLane> = (0..64)
        .map(|i| PhaseSampleLane {
            p,
            wi,
            u1: i as f64 / 64.0,
            u2: [((i * 37) % 64) as f64 / 64.0, ((i * 11) % 64) as f64 / 64.0],
        })
        .collect();
    let (wo, w, pdf) = m.phase_sample(&lanes, &[500.0, 600.0], 2);
    let lanes: Vec<PhaseEvalLane> = wo
        .iter()
        .map(|v| PhaseEvalLane {
            p,
            wi,
            wo: v.map(|x| x as f32),
        })
        .collect();
    let (vals, pdf2) = m.phase_eval(&lanes, &[500.0, 600.0], 2);
    for i in 0..64 {
        assert!(pdf[i] > 0.0);
        assert!(
            (pdf[i] - pdf2[i]).abs() < 1e-3 * pdf[i],
            "{} {}",
            pdf[i],
            pdf2[i]
        );
        assert!((w[2 * i] * pdf[i] - vals[2 * i]).abs() < 1e-3 * vals[2 * i].max(1e-9));
        // the pdf is a mixture of the channel values (throughput-proportional weights, `discrete` docs)
        let (lo, hi) = (
            vals[2 * i].min(vals[2 * i + 1]),
            vals[2 * i].max(vals[2 * i + 1]),
        );
        assert!(pdf2[i] >= lo * (1.0 - 1e-12) && pdf2[i] <= hi * (1.0 + 1e-12));
    }
}

/// `see_density`: the grains' equivalent of 4000 grains in the unit cube, spread by a density rising
/// threefold along x instead of their counts, keeps every bin's extinction and follows the density:
/// optical depths across the cube at x = 0.1 and 0.9 in its ratio (1.2 / 2.8, within 1 %).
#[test]
fn grains_equivalent_follows_the_density_drawn_from() {
    let mut m = medium_with(4000, crate::render::continuous::DEFAULT_CONTINUOUS_COUNT);
    let per_bin = |m: &DiscreteMedium| {
        let mut ext = [0.0f64; 2];
        let f = m.grains_field.as_ref().expect("the grains' equivalent");
        f.member_extinction(|member, e| ext[m.optics.bin[m.optics.code(member)] as usize] += e);
        ext
    };
    let counted = per_bin(&m);
    let identity = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];
    let density = Density::gradient(0, 1.0, 3.0).unwrap();
    m.see_density(&density, ([0.0; 3], [1.0; 3]), &identity)
        .unwrap();
    let spread = per_bin(&m);
    for b in 0..2 {
        // Within the rounding of a pick's shares to 1/65535.
        assert!(
            (spread[b] / counted[b] - 1.0).abs() < 1e-4,
            "{spread:?} vs {counted:?}"
        );
    }
    let field = m.grains_field.as_ref().unwrap();
    let depth =
        |x: f64| field.optical_depth(&RaySegment::new([x, -0.5, 0.5], [0.0, 1.0, 0.0], 0.0, 2.0));
    let ratio = depth(0.1) / depth(0.9);
    assert!((ratio / (1.2 / 2.8) - 1.0).abs() < 0.01, "{ratio}");
}

/// Polarisation (`mueller.rs`): a mixture's F11 is the unpolarised mixture's value and pdf, and each
/// other element is the particles' F11 × ratio weighed as F11 is — checked against single particles'
/// phase functions combined by hand. A bin without ratios depolarises (its elements beyond F11 are 0).
#[test]
fn mixture_mueller_weighs_elements_as_the_phase_function() {
    let mut m = medium(4000);
    let rows = |r: [f64; 3]| {
        let n = 2001;
        MuellerRatios::new(&vec![r[0]; n], &vec![r[1]; n], &vec![r[2]; n]).unwrap()
    };
    let ratios = [[-0.5, 0.3, 0.1], [0.2, -0.4, 0.05]];
    for (b, r) in m.bins.iter_mut().zip(ratios) {
        b.mueller = vec![rows(r), rows(r)];
    }
    let ls: Vec<_> = [480.0, 550.0, 600.0, 700.0].map(|l| m.bracket(l)).to_vec();
    let pi = [0.1, 0.2, 0.3, 0.4];
    let (a, b) = (0u32, 1u32); // bins 0 and 1
    let (both, only_a, only_b) = ([a, b], [a], [b]);
    let mix = |members| Mixture {
        members,
        scale: |j| m.optics.tau(j),
        ls: &ls,
        pi: &pi,
    };
    for k in 0..=40 {
        let mu = -1.0 + 2.0 * k as f64 / 40.0;
        let (mut v, mut e) = ([0.0; 4], [[0.0; 4]; 4]);
        let p = m.mixture_phase(&mix(&both), mu, &mut v);
        let pe = m.mixture_mueller(&mix(&both), mu, &mut e);
        assert!((p - pe).abs() <= 1e-12 * p, "pdf {p} vs {pe}");
        for c in 0..4 {
            let (mut fa, mut fb) = ([0.0; 4], [0.0; 4]);
            m.mixture_phase(&mix(&only_a), mu, &mut fa);
            m.mixture_phase(&mix(&only_b), mu, &mut fb);
            let w = |j: u32| m.optics.tau(j) * m.albedo_at(j, ls[c]);
            let (wa, wb) = (w(a), w(b));
            assert!((e[c][0] - v[c]).abs() <= 1e-12 * v[c], "F11 {e:?} vs {v:?}");
            for k in 0..3 {
                let want = (wa * fa[c] * ratios[0][k] + wb * fb[c] * ratios[1][k]) / (wa + wb);
                assert!(
                    (e[c][k + 1] - want).abs() <= 1e-6 * v[c],
                    "element {k} channel {c}: {} vs {want}",
                    e[c][k + 1]
                );
            }
        }
    }
    // Without ratios: a depolarizer.
    m.bins[1].mueller.clear();
    let mut e = [[0.0; 4]; 4];
    m.mixture_mueller(&mix(&only_b), 0.3, &mut e);
    assert!(e.iter().all(|row| row[0] > 0.0 && row[1..] == [0.0; 3]));
}

/// Ratios are checked (finite, within [−1, 1] up to rounding, rows of one length), clamped, and kept in
/// the phase table's node order (increasing μ: the reverse of θ's).
#[test]
fn mueller_ratios_are_checked_and_reversed() {
    let r = MuellerRatios::new(&[0.1, 0.2, 1.0 + 1e-9], &[1.0, 0.0, -1.0], &[0.0; 3]).unwrap();
    assert_eq!(r.len(), 3);
    assert_eq!(r.at((0, 0.0)), [1.0, -1.0, 0.0]); // θ = π first
    let mid = r.at((1, 0.5));
    assert!((mid[0] - 0.15).abs() < 1e-7 && (mid[1] - 0.5).abs() < 1e-7);
    assert!(MuellerRatios::new(&[1.1], &[0.0], &[0.0]).is_err());
    assert!(MuellerRatios::new(&[f64::NAN], &[0.0], &[0.0]).is_err());
    assert!(MuellerRatios::new(&[0.0, 0.0], &[0.0], &[0.0]).is_err());
}

/// `flat_field` (the Dr.Jit kernel's copy of the continuous classes' field), full and compact storage:
/// each cell's shares sum to 1 (cells of σ_t = 0 have no entry), one entry per bin in increasing order,
/// and σ_t × cell volume × share summed per bin is each bin's extinction as `member_extinction` gives it
/// (to f32's rounding of σ_t and the shares). None where every class is discrete.
#[test]
fn flat_field_keeps_each_bins_extinction() {
    assert!(medium_with(400, f64::INFINITY).flat_field().is_none());
    for storage in [Storage::Full, Storage::Compact] {
        let m = medium_stored(4000, 1.0, [0.5, 0.7], storage);
        let f = m.flat_field().expect("a continuous field");
        let cells = (f.dims[0] * f.dims[1] * f.dims[2]) as usize;
        assert_eq!((f.sigma.len(), f.start.len()), (cells, cells + 1));
        assert_eq!(f.start[cells] as usize, f.bin.len());
        let volume = f.cell[0] * f.cell[1] * f.cell[2];
        let mut per_bin = [0.0f64; 2];
        for c in 0..cells {
            let (a, b) = (f.start[c] as usize, f.start[c + 1] as usize);
            assert_eq!(a == b, f.sigma[c] <= 0.0, "cell {c}");
            if a == b {
                continue;
            }
            assert!(f.bin[a..b].windows(2).all(|w| w[0] < w[1]), "cell {c}");
            let total: f64 = f.share[a..b].iter().map(|&s| s as f64).sum();
            assert!(
                (total - 1.0).abs() < 1e-6,
                "cell {c}: shares sum to {total}"
            );
            for j in a..b {
                per_bin[f.bin[j] as usize] += f.sigma[c] as f64 * volume * f.share[j] as f64;
            }
        }
        let mut expected = [0.0f64; 2];
        m.field.as_ref().unwrap().member_extinction(|member, e| {
            expected[m.optics.bin(member)] += e;
        });
        for b in 0..2 {
            assert!(expected[b] > 0.0);
            let rel = per_bin[b] / expected[b] - 1.0;
            assert!(
                rel.abs() < 1e-6,
                "{storage:?} bin {b}: {per_bin:?} vs {expected:?}"
            );
        }
    }
}
