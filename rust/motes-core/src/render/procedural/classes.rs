//! A procedural cloud's classes (bin, radius level) with their probabilities, which of them stay
//! discrete, and one representative per bin for the continuous fields.

use super::{apply_linear, ProceduralSpec};
use crate::error::{require, OpticsError};
use crate::render::continuous::{class_is_continuous, CLASS_FLAG};
use crate::render::storage::LEVELS_PER_BIN;
use crate::space::grid::{size_class, SIZE_CLASSES};
use crate::space::vec3::{cross, dot};
use std::f64::consts::PI;

/// A class of a procedural cloud: bin, radius (scene units) and probability of a particle being it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ClassEntry {
    pub bin: u32,
    pub radius: f64,
    pub c_ext: f64,
    pub p: f64,
}

/// Every class of the distribution with a non-zero probability: per species, per bin, per radius
/// level (module docs), then one representative per bin (codes from `classes.len()`: a bin's
/// continuous classes as one, cross section their mean).
pub(crate) fn class_table(spec: &ProceduralSpec) -> Result<Vec<ClassEntry>, OpticsError> {
    let fractions = spec.cloud.share_fractions();
    require(
        "bin_edges_um (species)",
        spec.bin_edges_um.len() as f64,
        spec.bin_edges_um.len() == spec.cloud.species.len()
            && spec.first_bin.len() == spec.cloud.species.len(),
        "one list of edges and one first bin per species",
    )?;
    let mut out = Vec::new();
    for (s, ((_, psd), fraction)) in spec.cloud.species.iter().zip(&fractions).enumerate() {
        let edges = &spec.bin_edges_um[s];
        require(
            "bin_edges_um",
            edges.len() as f64,
            edges.len() >= 2 && edges.windows(2).all(|w| w[1] >= w[0]) && edges[0] > 0.0,
            "at least 2 positive, non-decreasing edges",
        )?;
        let nb = edges.len() - 1;
        let cdf = |r: f64| -> f64 { psd.cdf(r) };
        for b in 0..nb {
            let bin = spec.first_bin[s] + b as u32;
            require(
                "first_bin",
                bin as f64,
                (bin as usize) < spec.q_ext.len(),
                "< the number of bins with a q_ext",
            )?;
            let (lo, hi) = (edges[b], edges[b + 1]);
            let levels = if hi > lo { LEVELS_PER_BIN } else { 1 };
            let step = if hi > lo {
                (hi / lo).ln() / levels as f64
            } else {
                0.0
            };
            for l in 0..levels {
                let a = if b == 0 && l == 0 {
                    0.0
                } else {
                    cdf(lo * (l as f64 * step).exp())
                };
                let z = if b + 1 == nb && l + 1 == levels {
                    1.0
                } else {
                    cdf(lo * ((l + 1) as f64 * step).exp())
                };
                let p = fraction * (z - a).max(0.0);
                if p > 0.0 {
                    let r = lo * ((l as f64 + 0.5) * step).exp() * spec.scene_per_um;
                    out.push(ClassEntry {
                        bin,
                        radius: r,
                        c_ext: PI * r * r * spec.q_ext[bin as usize],
                        p,
                    });
                }
            }
        }
    }
    require(
        "bin_edges_um",
        out.len() as f64,
        !out.is_empty() && out.len() < (CLASS_FLAG - 1) as usize,
        "bins that hold some of the size distribution's radii",
    )?;
    Ok(out)
}

/// The box in scene units: its volume, mean chord 4V/S and edge lengths (of the parallelepiped).
pub(super) fn scene_box(spec: &ProceduralSpec) -> (f64, f64, [f64; 3]) {
    let (lo, hi) = (spec.cloud.lo, spec.cloud.hi);
    let e = [0, 1, 2].map(|a| {
        let mut v = [0.0; 3];
        v[a] = hi[a] - lo[a];
        apply_linear(&spec.transform, v)
    });
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let volume = dot(e[0], cross(e[1], e[2])).abs();
    let surface =
        2.0 * (norm(cross(e[0], e[1])) + norm(cross(e[1], e[2])) + norm(cross(e[2], e[0])));
    (volume, 4.0 * volume / surface, e.map(norm))
}

/// The cloud's box in scene units (`scene_box`).
pub(super) struct BoxShape {
    pub(super) volume: f64,
    pub(super) chord: f64,
    pub(super) extents: [f64; 3],
}

/// Which classes stay discrete: those whose size class a query cylinder holds fewer than
/// `continuous_count` of (crate::render::continuous::resolvable, with expected counts).
pub(super) fn discrete_classes(
    classes: &[ClassEntry],
    disks: &[(f64, f64)],
    count: f64,
    shape: &BoxShape,
    continuous_count: f64,
) -> Vec<bool> {
    let BoxShape {
        volume,
        chord,
        extents,
    } = *shape;
    let sigma: f64 = classes.iter().map(|c| count * c.p * c.c_ext).sum::<f64>() / volume;
    let length = if sigma > 0.0 {
        chord.min(1.0 / sigma)
    } else {
        chord
    };
    let reach_max = disks.iter().map(|d| d.0).fold(0.0, f64::max);
    // Per class: the expected number of grains and their disks' total area.
    let (mut grains, mut area) = ([0.0f64; SIZE_CLASSES], [0.0f64; SIZE_CLASSES]);
    for (c, d) in classes.iter().zip(disks) {
        grains[size_class(reach_max, d.0)] += count * c.p;
        area[size_class(reach_max, d.0)] += count * c.p * PI * d.0 * d.0;
    }
    let keep_class: Vec<bool> = area
        .iter()
        .zip(&grains)
        .map(|(a, n)| {
            let rms_reach = (a / (PI * n.max(1e-300))).sqrt();
            !class_is_continuous(a * length / volume, rms_reach, extents, continuous_count)
        })
        .collect();
    disks
        .iter()
        .map(|d| keep_class[size_class(reach_max, d.0)])
        .collect()
}

/// Per optics bin: the expected extinction per unit volume of its continuous classes (`cont`) and
/// of all its classes (`all`), and the probability of its continuous classes (`p_cont`).
pub(super) struct BinWeights {
    pub(super) cont: Vec<f64>,
    pub(super) all: Vec<f64>,
    pub(super) p_cont: Vec<f64>,
}

/// One representative per bin for the fields, pushed onto the classes (continuous): each bin's
/// continuous classes (all of its classes for the grains' equivalent) scatter as that bin.
pub(super) fn push_representatives(
    classes: &mut Vec<ClassEntry>,
    discrete: &mut Vec<bool>,
    count: f64,
    volume: f64,
    q_ext: &[f64],
) -> BinWeights {
    let bins = q_ext.len();
    let (mut w_cont, mut w_all, mut p_cont) = (vec![0.0; bins], vec![0.0; bins], vec![0.0; bins]);
    for (k, c) in classes.iter().enumerate() {
        let w = count * c.p * c.c_ext / volume;
        w_all[c.bin as usize] += w;
        if !discrete[k] {
            w_cont[c.bin as usize] += w;
            p_cont[c.bin as usize] += c.p;
        }
    }
    let mut p_bin = vec![0.0; bins];
    for c in classes.iter() {
        p_bin[c.bin as usize] += c.p;
    }
    for b in 0..bins {
        let (p, w) = if p_cont[b] > 0.0 {
            (p_cont[b], w_cont[b])
        } else {
            (p_bin[b], w_all[b])
        };
        let c_ext = if p > 0.0 {
            w * volume / (count * p)
        } else {
            0.0
        };
        classes.push(ClassEntry {
            bin: b as u32,
            radius: (c_ext / (PI * q_ext[b].max(1e-300))).sqrt(),
            c_ext,
            p: 0.0,
        });
        discrete.push(false);
    }
    BinWeights {
        cont: w_cont,
        all: w_all,
        p_cont,
    }
}
