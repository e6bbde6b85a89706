//! Cost of one traversal in a dense cloud (1e6 particles, R ~ 0.07, box 20): steps, references tested,
//! contributing particles and time per ray. `cargo run --release -p motes-core --example traverse_cost`
use motes_core::grid::ParticleGrid;
use std::time::Instant;

fn main() {
    let mut s = 1u64;
    let mut r = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64) / (1u64 << 53) as f64
    };
    let n = 1_000_000;
    let pos: Vec<[f64; 3]> = (0..n).map(|_| [20.0 * r() - 10.0, 20.0 * r() - 10.0, 20.0 * r() - 10.0]).collect();
    let rad: Vec<f64> = (0..n).map(|_| 0.008 + 0.004 * r()).collect();
    let c: Vec<f64> = rad.iter().map(|x| 2.0 * std::f64::consts::PI * x * x).collect();
    let g = ParticleGrid::build(&pos, &rad, &c, 1, 0.06, 1.0).unwrap();
    println!("dims {:?} bytes/particle {:.1}", g.dims(), g.bytes() as f64 / n as f64);
    let rays: Vec<([f64; 3], [f64; 3])> = (0..100_000)
        .map(|_| {
            let o = [20.0 * r() - 10.0, 20.0 * r() - 10.0, 20.0 * r() - 10.0];
            let mut d = [r() - 0.5, r() - 0.5, r() - 0.5];
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d = d.map(|x| x / l);
            (o, d)
        })
        .collect();
    let t = Instant::now();
    let mut hits = 0usize;
    for (o, d) in &rays {
        g.walk(*o, *d, 0.0, 40.0, |_, _, _| {
            hits += 1;
            true
        });
    }
    let dt = t.elapsed().as_secs_f64();
    println!("walk: {:.2} us/ray, {:.1} contributing particles/ray", dt / rays.len() as f64 * 1e6, hits as f64 / rays.len() as f64);
    let t = Instant::now();
    let mut v = [0.0];
    for (o, d) in &rays {
        g.optical_depth(*o, *d, 0.0, 40.0, &mut v);
    }
    println!("optical_depth: {:.2} us/ray (1 thread)", t.elapsed().as_secs_f64() / rays.len() as f64 * 1e6);
}
