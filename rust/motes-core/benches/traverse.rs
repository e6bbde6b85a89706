//! Cost of one traversal per ray, single-threaded (issue 10.2), in the two clouds of
//! `scripts/bench/bench_native.py`: `sparse` (the default scene's dust: 60 000 grains in a box of 20 units,
//! query radius 0.064) and `dense` (haze: 1e6 grains, R ~ 0.07). Rays start inside the box in random
//! directions and run 40 units (out of it): a full walk (every contributing particle), the grey optical
//! depth, and free flights to the first site (`sample_site`, what the renderer calls). `large`: the
//! Cornell box's 10^5 grains of 2 mm scaled to the box (reach ~ a tenth of a centre cell: every ray
//! comes near many cells; issue 25). `denser`: the Cornell box of 3e5 grains of 2 mm (its default
//! query radius, 0.2 cm) scaled to the box: optical depth ~9 across it.
//!
//! Each layout (cells per particle, the default first; spheres, quantised slots (`q`), and quantised
//! centre cells (`qc`, compact storage's)) is timed in interleaved rounds and the median round is
//! reported, so a busy machine shifts all columns alike.
//!
//!     cargo bench -p motes-core --bench traverse [-- sparse|dense|large|denser]
mod common;
use common::Lcg;
use motes_core::space::grid::{GridSettings, ParticleGrid, DEFAULT_CELLS_PER_PARTICLE};
use motes_core::space::ray::RaySegment;
use std::time::Instant;

const ROUNDS: usize = 5;

/// Microseconds per ray of `f` over all rays.
fn per_ray(rays: usize, f: impl FnOnce()) -> f64 {
    let t = Instant::now();
    f();
    t.elapsed().as_secs_f64() / rays as f64 * 1e6
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The grid layouts timed (cells per particle and "q" quantised, "c" centre cells), each built over
/// the particles; `TRAVERSE_LAYOUT=qc` (say) keeps only that layout (for a profiler).
fn grids(
    pos: &[[f64; 3]],
    rad: &[f64],
    c: &[f64],
    query_radius: f64,
) -> (Vec<(f64, &'static str)>, Vec<ParticleGrid>) {
    let d = DEFAULT_CELLS_PER_PARTICLE;
    let layouts = [
        (d, ""),
        (d, "q"),
        (d, "qc"),
        (4.0 * d, "qc"),
        (0.25 * d, "qc"),
        (0.1 * d, "qc"),
        (1.0, ""),
        (0.25, ""),
        (0.0625, ""),
    ];
    let only = std::env::var("TRAVERSE_LAYOUT").ok();
    let layouts: Vec<(f64, &'static str)> = layouts
        .into_iter()
        .filter(|(_, l)| only.as_deref().is_none_or(|o| o == *l))
        .collect();
    let grids: Vec<ParticleGrid> = layouts
        .iter()
        .map(|&(cpp, l)| {
            let settings = GridSettings::new(query_radius, cpp)
                .quantised(l.starts_with('q'))
                .centred(l == "qc");
            let mut g = ParticleGrid::build(pos, rad, c, 1, &settings).unwrap();
            g.release_stored(); // as a medium keeps it
            g
        })
        .collect();
    (layouts, grids)
}

fn run(name: &str, n: usize, r_min: f64, r_span: f64, query_radius: f64) {
    let mut r = Lcg(1);
    let point = |r: &mut Lcg| [0; 3].map(|_| 20.0 * r.next() - 10.0);
    let pos: Vec<[f64; 3]> = (0..n).map(|_| point(&mut r)).collect();
    let rad: Vec<f64> = (0..n).map(|_| r_min + r_span * r.next()).collect();
    let c: Vec<f64> = rad
        .iter()
        .map(|x| 2.0 * std::f64::consts::PI * x * x)
        .collect();
    let rays: Vec<RaySegment> = (0..200_000)
        .map(|_| {
            let o = point(&mut r);
            let d = [r.next() - 0.5, r.next() - 0.5, r.next() - 0.5];
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            RaySegment::new(o, d.map(|x| x / l), 0.0, 40.0)
        })
        .collect();
    let (layouts, grids) = grids(&pos, &rad, &c, query_radius);
    let mut times = vec![[const { Vec::new() }; 3]; grids.len()];
    let (mut hits, mut sites) = (0usize, 0usize);
    for _ in 0..ROUNDS {
        for (g, t) in grids.iter().zip(times.iter_mut()) {
            hits = 0;
            t[0].push(per_ray(rays.len(), || {
                for ray in &rays {
                    g.walk(ray, |_, _, _| {
                        hits += 1;
                        true
                    });
                }
            }));
            let mut v = [0.0];
            t[1].push(per_ray(rays.len(), || {
                for ray in &rays {
                    g.optical_depth(ray, &mut v);
                }
            }));
            sites = 0;
            t[2].push(per_ray(rays.len(), || {
                for (k, ray) in rays.iter().enumerate() {
                    let u = (k as f64 + 0.5) / rays.len() as f64;
                    sites += g.sample_site(ray, &[], u, 1e-6).0.is_some() as usize;
                }
            }));
        }
    }
    println!(
        "{name}: {n} particles, {:.1} contributing and {:.0} % interacting per ray (median of {ROUNDS} rounds)",
        hits as f64 / rays.len() as f64,
        100.0 * sites as f64 / rays.len() as f64
    );
    for ((&(cpp, l), g), t) in layouts.iter().zip(&grids).zip(times) {
        let [w, o, f] = t.map(median);
        println!(
            "  cells/particle {cpp:<6} {l:<2} cells {:?}, {:.1} bytes/particle | walk {w:.2} us/ray, optical_depth {o:.2} us/ray, free flight {f:.2} us/ray",
            g.dims(),
            g.bytes() as f64 / n as f64,
        );
    }
}

fn main() {
    let only = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let wanted = |name: &str| only.as_deref().is_none_or(|o| o == name);
    if wanted("sparse") {
        run("sparse", 60_000, 0.0005, 0.004, 0.064);
    }
    if wanted("dense") {
        run("dense", 1_000_000, 0.008, 0.004, 0.06);
    }
    if wanted("large") {
        run("large", 100_000, 0.07, 0.0, 0.076);
    }
    if wanted("denser") {
        run("denser", 300_000, 0.074, 0.0, 0.0746);
    }
}
