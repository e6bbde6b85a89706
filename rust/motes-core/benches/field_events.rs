//! Cost per scattering event of the native render path's packet interface in a dense cloud (issue 25):
//! the dense Cornell box's grains (3e5 of 2 mm in a 56 cm box, optical depth ~24 across), single-threaded,
//! without Mitsuba around it. Paths in packets of 16 lanes enter the box as one pixel's camera rays and
//! scatter up to 12 times; each event is what `volpath` asks of the medium: the shadow ray's free flight
//! (which settles the event), the phase function's evaluation towards the light, its sample, and the
//! next free flight. Prints microseconds per event and per kind of call (each kind timed on its own
//! calls, so the columns add up to about the total).
//!
//!     cargo bench -p motes-core --bench field_events
mod common;
use common::Lcg;
use motes_core::ensemble::phase_table::PhaseTable;
use motes_core::render::discrete::{
    BinOptics, DiscreteMedium, MediumSettings, PacketRay, PhaseEvalLane, PhaseSampleLane,
    PACKET_LANES,
};
use motes_core::render::storage::Storage;
use std::f64::consts::PI;
use std::time::{Duration, Instant};

/// Henyey-Greenstein on a fine grid (the grains' GOA tables have a few thousand nodes).
fn table(g: f64) -> PhaseTable {
    let theta: Vec<f64> = (0..3001).map(|i| PI * i as f64 / 3000.0).collect();
    let f: Vec<f64> = theta
        .iter()
        .map(|t| (1.0 - g * g) / (4.0 * PI * (1.0 + g * g - 2.0 * g * t.cos()).powf(1.5)))
        .collect();
    PhaseTable::new(&theta, &f).unwrap()
}

const HALF: f64 = 28.0;
const EVENTS_PER_PATH: usize = 12;
/// The channels' wavelengths (RGB), nm.
const LAMBDA: [f64; 3] = [630.0, 532.0, 467.0];

fn medium() -> DiscreteMedium {
    let mut r = Lcg(5);
    let n = 300_000;
    let pos: Vec<[f64; 3]> = (0..n)
        .map(|_| [0; 3].map(|_| HALF * (2.0 * r.next() - 1.0)))
        .collect();
    let rad = vec![0.2; n];
    let c = 2.0 * PI * 0.04;
    let bins = vec![BinOptics {
        albedo: vec![0.97, 0.98, 0.99],
        phase: vec![table(0.84), table(0.82), table(0.8)],
        mueller: Vec::new(),
    }];
    let settings = MediumSettings {
        query_radius: 0.0,
        tau_max: 1.0,
        cells_per_particle: 0.125,
        continuous_count: 16.0,
        seed: 1,
        storage: Storage::Compact,
        ..MediumSettings::default()
    };
    DiscreteMedium::build(
        &pos,
        &rad,
        1.0,
        &|_| c,
        &vec![0; n],
        bins,
        vec![467.0, 532.0, 630.0],
        &settings,
    )
    .unwrap()
}

#[derive(Default)]
struct Clock {
    flights: Duration,
    shadows: Duration,
    evals: Duration,
    samples: Duration,
    events: u64,
}

fn timed<R>(acc: &mut Duration, f: impl FnOnce() -> R) -> R {
    let t = Instant::now();
    let out = f();
    *acc += t.elapsed();
    out
}

/// A lane's event: where it lies and the incident direction.
type AtEvent = Option<([f32; 3], [f32; 3])>;

fn main() {
    let m = medium();
    let mut r = Lcg(9);
    let mut clock = Clock::default();
    let total = Instant::now();
    for _packet in 0..20_000 {
        let mut rays = camera_rays(&mut r);
        let mut t = [None; PACKET_LANES];
        timed(&mut clock.flights, || {
            m.packet_free_flights(&rays, &LAMBDA, 3, &mut t)
        });
        for _depth in 0..EVENTS_PER_PATH {
            if !scatter(&m, &mut r, &mut clock, &mut rays, &mut t) {
                break;
            }
        }
    }
    let per = |d: Duration| d.as_secs_f64() / clock.events as f64 * 1e6;
    println!(
        "{} events: {:.3} us per event (free flights {:.3}, shadow rays {:.3}, phase eval {:.3}, phase sample {:.3})",
        clock.events,
        total.elapsed().as_secs_f64() / clock.events as f64 * 1e6,
        per(clock.flights),
        per(clock.shadows),
        per(clock.evals),
        per(clock.samples)
    );
}

/// One pixel's camera rays entering the box through its open face.
fn camera_rays(r: &mut Lcg) -> [Option<PacketRay>; PACKET_LANES] {
    let (x, y) = (50.0 * r.next() - 25.0, 50.0 * r.next() - 25.0);
    let mut rays: [Option<PacketRay>; PACKET_LANES] = [None; PACKET_LANES];
    for ray in rays.iter_mut() {
        let o = [x + 0.05 * r.next(), y + 0.05 * r.next(), HALF - 1e-3];
        let d = [(x * -0.005) as f32, (y * -0.005) as f32, -1.0];
        let l = (d[0] * d[0] + d[1] * d[1] + 1.0f32).sqrt();
        *ray = Some((o.map(|v| v as f32), d.map(|v| v / l), 100.0));
    }
    rays
}

/// One event of each lane whose free flight (`rays`, distances `t`) found a site: NEE, the phase
/// sample, and the scattered rays' free flights into `rays` and `t`. False where no lane has an event.
fn scatter(
    m: &DiscreteMedium,
    r: &mut Lcg,
    clock: &mut Clock,
    rays: &mut [Option<PacketRay>; PACKET_LANES],
    t: &mut [Option<f64>; PACKET_LANES],
) -> bool {
    let at = |o: [f32; 3], d: [f32; 3], t: f64| [0, 1, 2].map(|a| d[a].mul_add(t as f32, o[a]));
    let mut at_event: [AtEvent; PACKET_LANES] = [None; PACKET_LANES];
    for i in 0..PACKET_LANES {
        if let (Some((o, d, _)), Some(t)) = (rays[i], t[i]) {
            at_event[i] = Some((at(o, d, t), d));
        }
    }
    if at_event.iter().all(|e| e.is_none()) {
        return false;
    }
    clock.events += at_event.iter().flatten().count() as u64;
    next_event_estimation(m, r, clock, &at_event);
    let (wo, spdf) = phase_samples(m, r, clock, &at_event);
    // The scattered rays (the box's walls end them: they leave the medium).
    for i in 0..PACKET_LANES {
        rays[i] = match at_event[i] {
            Some((p, _)) if spdf[i] > 0.0 => Some((p, wo[i].map(|x| x as f32), 1e3)),
            _ => None,
        };
        if r.next() < 0.02 {
            rays[i] = None; // a path ends now and then (roulette, a wall)
        }
    }
    timed(&mut clock.flights, || {
        m.packet_free_flights(rays, &LAMBDA, 3, t)
    });
    true
}

/// NEE at the lanes' events: a shadow ray towards the ceiling light, then the phase function towards
/// it.
fn next_event_estimation(
    m: &DiscreteMedium,
    r: &mut Lcg,
    clock: &mut Clock,
    at_event: &[AtEvent; PACKET_LANES],
) {
    let mut shadow = [None; PACKET_LANES];
    let mut towards = [[0.0f32; 3]; PACKET_LANES];
    for i in 0..PACKET_LANES {
        if let Some((p, _)) = at_event[i] {
            let target = [10.0 * r.next() - 5.0, HALF, 10.0 * r.next() - 5.0];
            let d = [0, 1, 2].map(|a| target[a] - p[a] as f64);
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            towards[i] = d.map(|x| (x / l) as f32);
            shadow[i] = Some((p, towards[i], l as f32));
        }
    }
    let mut ts = [None; PACKET_LANES];
    timed(&mut clock.shadows, || {
        m.packet_free_flights(&shadow, &LAMBDA, 3, &mut ts)
    });
    let evals: [Option<PhaseEvalLane>; PACKET_LANES] = std::array::from_fn(|i| {
        at_event[i].map(|(p, d)| PhaseEvalLane {
            p,
            wi: d.map(|x| -x),
            wo: towards[i],
        })
    });
    let (mut values, mut pdf) = ([0.0; 3 * PACKET_LANES], [0.0; PACKET_LANES]);
    timed(&mut clock.evals, || {
        m.packet_phase_eval(&evals, &LAMBDA, 3, &mut values, &mut pdf)
    });
}

/// The phase samples at the lanes' events: their directions and pdfs.
fn phase_samples(
    m: &DiscreteMedium,
    r: &mut Lcg,
    clock: &mut Clock,
    at_event: &[AtEvent; PACKET_LANES],
) -> ([[f64; 3]; PACKET_LANES], [f64; PACKET_LANES]) {
    let samples: [Option<PhaseSampleLane>; PACKET_LANES] = std::array::from_fn(|i| {
        at_event[i].map(|(p, d)| PhaseSampleLane {
            p,
            wi: d.map(|x| -x),
            u1: r.next(),
            u2: [r.next(), r.next()],
        })
    });
    let (mut wo, mut weight, mut spdf) = (
        [[0.0; 3]; PACKET_LANES],
        [0.0; 3 * PACKET_LANES],
        [0.0; PACKET_LANES],
    );
    timed(&mut clock.samples, || {
        m.packet_phase_sample(&samples, &LAMBDA, 3, &mut wo, &mut weight, &mut spdf, false)
    });
    (wo, spdf)
}
