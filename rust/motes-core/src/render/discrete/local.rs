//! Local scattering at points (paper Eq. 24): the particles whose inclusion balls hold a point, as a
//! scattering coefficient and a phase function there, and samples of that phase function.

use super::channels::{lane_wavelengths, uniform_channels};
use super::phase::{null_sample, unzip_samples, Mixture, Sample};
use super::DiscreteMedium;
use crate::space::vec3::normalise;
use rayon::prelude::*;
use std::f64::consts::PI;

impl DiscreteMedium {
    /// Local scattering at points (paper Eq. 24 with the per-particle normalisation of the grid): the
    /// particles whose inclusion ball (R_i = r_c + r_i) contains p each add C_s,i / V_i with
    /// V_i = 4/3 π R_i³, so that E[σ_s(p)] is the bulk σ_s. Returns σ_s per channel and
    /// Q_c(μ) = σ_s,c f_c(μ) (1/sr per unit length) at the given μ = cos θ, each `n × channels`.
    pub fn local_scattering(
        &self,
        p: &[[f64; 3]],
        mu: &[f64],
        lambda: &[f64],
        channels: usize,
    ) -> (Vec<f64>, Vec<f64>) {
        let res: Vec<(Vec<f64>, Vec<f64>)> = (0..p.len())
            .into_par_iter()
            .map(|i| {
                let members = self.local_members(p[i]);
                let lam = lane_wavelengths(lambda, channels, i);
                let ls: Vec<_> = lam.iter().map(|&l| self.bracket(l)).collect();
                let scale = |j: u32| self.local_weight(j, p[i]);
                let sigma: Vec<f64> = ls
                    .iter()
                    .map(|&l| {
                        members
                            .iter()
                            .map(|&j| scale(j) * self.albedo_at(j, l))
                            .sum()
                    })
                    .collect();
                let mut f = vec![0.0; channels];
                let mixture = Mixture {
                    members: &members,
                    scale,
                    ls: &ls,
                    pi: &uniform_channels(channels),
                };
                self.mixture_phase(&mixture, mu[i].clamp(-1.0, 1.0), &mut f);
                let q = f.iter().zip(&sigma).map(|(a, b)| a * b).collect();
                (sigma, q)
            })
            .collect();
        let sigma = res.iter().flat_map(|r| r.0.iter().copied()).collect();
        (sigma, res.into_iter().flat_map(|r| r.1).collect())
    }

    /// C_t,i / V_i of particle i (grey), the weight of a particle in the query sphere of Eq. 24 (a
    /// particle of the continuous field is spread over its cell: V_i is the cell's volume).
    fn local_weight(&self, j: u32, p: [f64; 3]) -> f64 {
        // A procedural cloud's field: the σ_t its class carries at p.
        if let (Some(f), true) = (&self.field, self.optics.in_field(j)) {
            if let Some(s) = f.shared_sigma(p, j) {
                return s;
            }
        }
        let r = self.optics.reach(j);
        let volume = match (&self.field, self.optics.in_field(j)) {
            (Some(f), true) => f.cell_volume(),
            _ => 4.0 / 3.0 * PI * r * r * r,
        };
        self.optics.c_ext(j) / volume
    }

    /// The particles local to `p` (Eq. 24's query sphere): those whose ball contains it, and the
    /// continuous field's particles of its cell.
    fn local_members(&self, p: [f64; 3]) -> Vec<u32> {
        let mut m = self
            .grid
            .as_ref()
            .map_or_else(Vec::new, |g| g.containing(p));
        if let Some(f) = &self.field {
            if let Some(c) = f.cell_at(p) {
                m.extend(f.members(c));
            }
        }
        m
    }

    /// Sample scattered directions from the local mixture at points (see [`Self::local_scattering`]):
    /// a particle with probability ∝ its local scattering weight, then its tabulated phase function.
    /// `w_in` is the propagation direction. Returns (wo, weight per channel = f_c / pdf, pdf); pdf 0
    /// where no particle is local.
    pub fn sample_local(
        &self,
        p: &[[f64; 3]],
        w_in: &[[f64; 3]],
        lambda: &[f64],
        channels: usize,
        u1: &[f64],
        u2: &[[f64; 2]],
    ) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
        let res: Vec<Sample> = (0..p.len())
            .into_par_iter()
            .map(|i| {
                let members = self.local_members(p[i]);
                let Some(dir) = normalise(w_in[i]) else {
                    return null_sample(channels);
                };
                let lam = lane_wavelengths(lambda, channels, i);
                let ls: Vec<_> = lam.iter().map(|&l| self.bracket(l)).collect();
                let mixture = Mixture {
                    members: &members,
                    scale: |j| self.local_weight(j, p[i]),
                    ls: &ls,
                    pi: &uniform_channels(channels),
                };
                self.mixture_sample(&mixture, dir, u1[i], u2[i])
            })
            .collect();
        unzip_samples(res)
    }
}
