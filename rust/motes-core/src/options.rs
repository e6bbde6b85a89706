//! The environment switches of the core: side-by-side comparisons of a choice the core makes for
//! itself (`scripts/bench/bench_quantise.py --switch`), never settings a scene needs. Unset, each
//! leaves the core's own choice; none changes what a render converges to, only how it gets there.
//!
//! | Variable | Values | Read | What it switches |
//! |---|---|---|---|
//! | `MOTES_QUANTISE` | `0`: off | at each discrete medium's build ([`BuildSwitches`]) | compact storage's quantised grid slots (`crate::space::grid`, "Quantised slots"); off: spheres |
//! | `MOTES_CENTRE_CELLS` | `1`: always, `0`: never | at each discrete medium's build ([`BuildSwitches`]) | compact storage keeping its grains by their centres' cells; unset: from `CENTRE_CELLS_FROM` discrete grains on (`crate::render::discrete`) |
//! | `MOTES_BEAM` | `0`: off | at each discrete medium's build ([`BuildSwitches`]) | a packet's rays from no event walking the grains as one beam (`ParticleGrid::sample_sites_beam`); off: one by one (the same sites) |
//! | `MOTES_UNIFORM_MAJORANT` | `0`: off | at each continuous field's build ([`uniform_majorant`]) | delta tracking against one majorant where the field's blocks are near-uniform; off: block by block |
//! | `MOTES_SIMD` | `sse`, `avx2` | once per process ([`simd_cap`], cached by `crate::simd`) | `sse`: the grid's narrow walks and nothing wider; `avx2`: no AVX-512 (the continuous fields' lockstep free flights, a packet's side-by-side phase samples); unset: the widest the CPU has |
//!
//! The build-time switches are read at every build, not once per process: a benchmark toggles them
//! between two loads of the same scene in one process.

/// An on-by-default switch of the environment: off where set to "0".
fn env_flag(name: &str) -> bool {
    std::env::var(name).map_or(true, |v| v != "0")
}

/// `MOTES_UNIFORM_MAJORANT`: whether a continuous field may use one majorant for all its cells.
pub(crate) fn uniform_majorant() -> bool {
    env_flag("MOTES_UNIFORM_MAJORANT")
}

/// The widest SIMD level `MOTES_SIMD` allows (`crate::simd` adds what the CPU has).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimdCap {
    /// `sse`: the x86-64 baseline everywhere.
    Sse,
    /// `avx2`: AVX2 + FMA at most, no AVX-512.
    Avx2,
    /// Unset (or anything else): the widest the CPU has.
    Widest,
}

/// `MOTES_SIMD` as a [`SimdCap`].
pub(crate) fn simd_cap() -> SimdCap {
    match std::env::var("MOTES_SIMD").as_deref() {
        Ok("sse") => SimdCap::Sse,
        Ok("avx2") => SimdCap::Avx2,
        _ => SimdCap::Widest,
    }
}

/// The switches a discrete medium's build reads (module docs), read once at its start and handed
/// down to the parts of the build that use them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BuildSwitches {
    /// `MOTES_QUANTISE`: compact storage quantises its grid slots.
    pub quantise: bool,
    /// `MOTES_CENTRE_CELLS`: compact storage keeps its grains by their centres' cells always
    /// (`Some(true)`), never (`Some(false)`), or from enough discrete grains on (`None`).
    pub centre_cells: Option<bool>,
    /// `MOTES_BEAM`: a packet's rays from no event walk the grains as beams.
    pub beams: bool,
}

impl Default for BuildSwitches {
    /// Every switch as it is without the environment.
    fn default() -> Self {
        BuildSwitches {
            quantise: true,
            centre_cells: None,
            beams: true,
        }
    }
}

impl BuildSwitches {
    /// The switches as the environment sets them now.
    pub fn from_env() -> Self {
        BuildSwitches {
            quantise: env_flag("MOTES_QUANTISE"),
            centre_cells: match std::env::var("MOTES_CENTRE_CELLS").as_deref() {
                Ok("1") => Some(true),
                Ok("0") => Some(false),
                _ => None,
            },
            beams: env_flag("MOTES_BEAM"),
        }
    }
}
