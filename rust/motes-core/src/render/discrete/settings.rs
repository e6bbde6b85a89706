//! What a discrete medium's build takes besides its particles and their optics ([`MediumSettings`]),
//! and the checks of a build's inputs, each naming its argument.

use super::{BinOptics, DEFAULT_TAU_MAX};
use crate::error::{require, require_len, OpticsError};
use crate::render::continuous::{Column, CLASS_FLAG, DEFAULT_CONTINUOUS_COUNT};
use crate::render::procedural::{ProceduralSpec, DEFAULT_CACHE_BYTES};
use crate::render::storage::Storage;
use crate::space::grid::{check_particles, first_where, GridSettings, DEFAULT_CELLS_PER_PARTICLE};

/// The settings of [`DiscreteMedium::build`](super::DiscreteMedium::build) and
/// [`DiscreteMedium::procedural`](super::DiscreteMedium::procedural) (module docs of
/// `crate::render::discrete`); [`Default`] gives the documented defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MediumSettings {
    /// r_c, the query radius added to every particle's radius (scene units; default 0).
    pub query_radius: f64,
    /// The cap on each disk's optical depth ([`DEFAULT_TAU_MAX`]; `f64::INFINITY`: none).
    pub tau_max: f64,
    /// Grid cells per particle ([`DEFAULT_CELLS_PER_PARTICLE`]).
    pub cells_per_particle: f64,
    /// Size classes holding at least this many particles per query cylinder are sampled as a
    /// continuous medium (`crate::render::continuous`; [`DEFAULT_CONTINUOUS_COUNT`];
    /// `f64::INFINITY`: none, the medium is exact).
    pub continuous_count: f64,
    /// The seed of the free flights' random numbers (default 0).
    pub seed: u64,
    /// How stored particles are kept (`crate::render::storage`; default compact). A procedural cloud
    /// keeps classes whatever this says.
    pub storage: Storage,
    /// The bytes of a procedural cloud's bricks kept ([`DEFAULT_CACHE_BYTES`]; stored particles:
    /// unused).
    pub cache_bytes: usize,
}

impl Default for MediumSettings {
    fn default() -> Self {
        MediumSettings {
            query_radius: 0.0,
            tau_max: DEFAULT_TAU_MAX,
            cells_per_particle: DEFAULT_CELLS_PER_PARTICLE,
            continuous_count: DEFAULT_CONTINUOUS_COUNT,
            seed: 0,
            storage: Storage::default(),
            cache_bytes: DEFAULT_CACHE_BYTES,
        }
    }
}

impl MediumSettings {
    /// The grid's settings of these.
    pub(super) fn grid(&self) -> GridSettings {
        GridSettings::new(self.query_radius, self.cells_per_particle)
    }
}

/// The checks of a particle set and the medium's settings that need no optics: one home for these
/// rules, called by [`DiscreteMedium::build`](super::DiscreteMedium::build) and, before it spends
/// minutes on optics tables, by the Python layer (so that a bad setting fails at once).
pub fn check_particles_and_settings(
    positions: &[[f64; 3]],
    radius: &[f64],
    settings: &MediumSettings,
) -> Result<(), OpticsError> {
    check_particles(positions, radius, &settings.grid())?;
    let (tau_max, continuous_count) = (settings.tau_max, settings.continuous_count);
    require("tau_max", tau_max, tau_max > 0.0, "> 0 (inf: no cap)")?;
    require(
        "continuous_count",
        continuous_count,
        continuous_count > 0.0,
        "> 0 (inf: every class discrete)",
    )
}

/// The particles of a build as it takes them: `positions`, `radius` × `radius_scale` (scene units),
/// `c_ext` and each particle's `bin`.
pub(super) struct ParticleInputs<'a> {
    pub positions: &'a [[f64; 3]],
    pub radius: &'a [f64],
    pub radius_scale: f64,
    pub c_ext: Column<'a>,
    pub bin: &'a [u32],
}

/// The checks of [`DiscreteMedium::build`](super::DiscreteMedium::build)'s inputs, each naming its
/// argument.
pub(super) fn check_build_inputs(
    p: &ParticleInputs,
    bins: &[BinOptics],
    lambda: &[f64],
    settings: &MediumSettings,
) -> Result<(), OpticsError> {
    let n = p.positions.len();
    // Indices of particles stay below CLASS_FLAG (the continuous fields' class members use that bit).
    require(
        "positions (count)",
        n as f64,
        (n as u64) < CLASS_FLAG as u64,
        "< 2^31 particles",
    )?;
    require_len("bin (length)", p.bin.len(), n, "one per particle")?;
    require(
        "radius_scale",
        p.radius_scale,
        p.radius_scale.is_finite() && p.radius_scale > 0.0,
        "finite and > 0",
    )?;
    check_particles_and_settings(p.positions, p.radius, settings)?;
    if let Some(b) =
        first_where(n.min(p.bin.len()), |i| p.bin[i] as usize >= bins.len()).map(|i| p.bin[i])
    {
        require("bin (index)", b as f64, false, "< number of bins")?;
    }
    let bad = |i: usize| {
        let c = (p.c_ext)(i);
        !(c.is_finite() && c >= 0.0)
    };
    if let Some(i) = first_where(n, bad) {
        let c = (p.c_ext)(i);
        require("c_ext", c, c.is_finite() && c >= 0.0, "finite and >= 0")?;
    }
    check_optics(bins, lambda)
}

/// The checks of [`DiscreteMedium::procedural`](super::DiscreteMedium::procedural)'s inputs: the
/// settings and optics as for stored particles (one stand-in particle), and the bins' efficiencies.
pub(super) fn check_procedural_inputs(
    spec: &ProceduralSpec,
    bins: &[BinOptics],
    lambda: &[f64],
    settings: &MediumSettings,
) -> Result<(), OpticsError> {
    let stand_in = ParticleInputs {
        positions: &[[0.0; 3]],
        radius: &[1.0],
        radius_scale: 1.0,
        c_ext: &|_| 1.0,
        bin: &[0],
    };
    // The stand-in's one particle would bound cells_per_particle by a grid of one particle: a procedural
    // cloud's grids are its bricks', whose range `ProceduralGrains` checks once it knows their size.
    let cells = settings.cells_per_particle;
    require(
        "cells_per_particle",
        cells,
        cells.is_finite() && cells > 0.0,
        "finite and > 0",
    )?;
    let stand_in_settings = MediumSettings {
        cells_per_particle: DEFAULT_CELLS_PER_PARTICLE,
        ..*settings
    };
    check_build_inputs(&stand_in, bins, lambda, &stand_in_settings)?;
    require_len("q_ext", spec.q_ext.len(), bins.len(), "one per bin")?;
    for &q in &spec.q_ext {
        require("q_ext", q, q.is_finite() && q >= 0.0, "finite and >= 0")?;
    }
    Ok(())
}

/// The checks of the optics bins and their wavelengths.
fn check_optics(bins: &[BinOptics], lambda: &[f64]) -> Result<(), OpticsError> {
    require(
        "lambda (length)",
        lambda.len() as f64,
        !lambda.is_empty(),
        ">= 1",
    )?;
    for w in lambda.windows(2) {
        require("lambda", w[1], w[1] > w[0], "strictly increasing")?;
    }
    for (b, o) in bins.iter().enumerate() {
        require(
            "bins (albedo per wavelength)",
            b as f64,
            o.albedo.len() == lambda.len() && o.phase.len() == lambda.len(),
            "one albedo and one phase table per wavelength",
        )?;
        for &a in &o.albedo {
            require(
                "albedo",
                a,
                a.is_finite() && (0.0..=1.0 + 1e-9).contains(&a),
                "in [0, 1]",
            )?;
        }
    }
    Ok(())
}
