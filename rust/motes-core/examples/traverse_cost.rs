//! Cost of one traversal per ray, single-threaded, in the two clouds of `scripts/bench_native.py`:
//! `sparse` (the default scene's dust: 60 000 grains in a box of 20 units, query radius 0.064) and `dense`
//! (haze: 1e6 grains, R ~ 0.07). Rays start inside the box in random directions and run 40 units (out of
//! it): a full walk (every contributing particle), the grey optical depth, and free flights to the first
//! site (`sample_site`, what the renderer calls).
//!
//!     cargo run --release -p motes-core --example traverse_cost
use motes_core::grid::ParticleGrid;
use std::time::Instant;

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64) / (1u64 << 53) as f64
    }
}

fn run(name: &str, n: usize, r_min: f64, r_span: f64, query_radius: f64) {
    let mut r = Lcg(1);
    let pos: Vec<[f64; 3]> = (0..n)
        .map(|_| {
            [
                20.0 * r.next() - 10.0,
                20.0 * r.next() - 10.0,
                20.0 * r.next() - 10.0,
            ]
        })
        .collect();
    let rad: Vec<f64> = (0..n).map(|_| r_min + r_span * r.next()).collect();
    let c: Vec<f64> = rad
        .iter()
        .map(|x| 2.0 * std::f64::consts::PI * x * x)
        .collect();
    let g = ParticleGrid::build(&pos, &rad, &c, 1, query_radius, 1.0).unwrap();
    let rays: Vec<([f64; 3], [f64; 3])> = (0..200_000)
        .map(|_| {
            let o = [
                20.0 * r.next() - 10.0,
                20.0 * r.next() - 10.0,
                20.0 * r.next() - 10.0,
            ];
            let d = [r.next() - 0.5, r.next() - 0.5, r.next() - 0.5];
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            (o, d.map(|x| x / l))
        })
        .collect();
    let per_ray = |t: Instant| t.elapsed().as_secs_f64() / rays.len() as f64 * 1e6;
    let t = Instant::now();
    let mut hits = 0usize;
    for (o, d) in &rays {
        g.walk(*o, *d, 0.0, 40.0, |_, _, _| {
            hits += 1;
            true
        });
    }
    let walk = per_ray(t);
    let t = Instant::now();
    let mut v = [0.0];
    for (o, d) in &rays {
        g.optical_depth(*o, *d, 0.0, 40.0, &mut v);
    }
    let depth = per_ray(t);
    let t = Instant::now();
    let mut sites = 0usize;
    for (k, (o, d)) in rays.iter().enumerate() {
        let u = (k as f64 + 0.5) / rays.len() as f64;
        sites += g.sample_site(*o, *d, 0.0, 40.0, &[], u, 1e-6).0.is_some() as usize;
    }
    let flight = per_ray(t);
    println!(
        "{name}: {n} particles, cells {:?}, {:.1} bytes/particle, {:.1} contributing/ray | walk {walk:.2} us/ray, optical_depth {depth:.2} us/ray, free flight {flight:.2} us/ray ({:.0} % interact)",
        g.dims(),
        g.bytes() as f64 / n as f64,
        hits as f64 / rays.len() as f64,
        100.0 * sites as f64 / rays.len() as f64
    );
}

fn main() {
    run("sparse", 60_000, 0.0005, 0.004, 0.064);
    run("dense", 1_000_000, 0.008, 0.004, 0.06);
}
