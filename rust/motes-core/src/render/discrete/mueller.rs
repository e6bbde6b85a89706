//! Polarisation (issue 45): a bin's Mueller ratios beside its phase tables, and a site's Mueller
//! matrix per channel.
//!
//! A sphere scatters with the Mueller matrix (Bohren & Huffman 1983, §4.4; Stokes vectors referenced to
//! the scattering plane)
//!
//! ```text
//! F11 F12  0   0
//! F12 F11  0   0
//!  0   0  F33 F34
//!  0   0 −F34 F33
//! ```
//!
//! A bin keeps, per tabulated wavelength, its ensemble's ratios F12/F11, F33/F11 and F34/F11 on the
//! nodes of its phase table (F11): the ratios are bounded by 1, so linear interpolation keeps every
//! interpolated matrix physical (|F_ij| ≤ F11), and the sampling, which draws from F11 alone, is the
//! unpolarised one unchanged. A site's mixture weighs each particle's elements as the unpolarised
//! mixture weighs its F11 (`phase.rs`, Eq. 24): a mixture of spheres has the same four-element form.
//! A bin without ratios (a user's phase function, Henyey–Greenstein) depolarises: its renderer returns
//! F11 as Mitsuba's own phase functions do in polarised variants.

use super::channels::event_channels;
use super::phase::{bin_albedo, Mixture};
use super::{BinOptics, DiscreteMedium, PhaseEvalLane, MAX_CHANNELS};
use crate::error::{require, OpticsError};

/// The four distinct elements (F11, F12, F33, F34) of one channel.
pub type Elements = [f64; 4];

/// F12/F11, F33/F11 and F34/F11 of one phase table, on its nodes (in its order of increasing μ).
#[derive(Clone, Debug, Default)]
pub struct MuellerRatios {
    r: Vec<[f32; 3]>,
}

impl MuellerRatios {
    /// From the ratios at increasing θ (the order of the angles a phase table is built from). Each must
    /// be finite and within [−1, 1] up to rounding (1e-6); they are clamped to it.
    pub fn new(r12: &[f64], r33: &[f64], r34: &[f64]) -> Result<Self, OpticsError> {
        require(
            "mueller (length)",
            r33.len() as f64,
            r12.len() == r33.len() && r12.len() == r34.len(),
            "three rows of equal length",
        )?;
        let mut r = Vec::with_capacity(r12.len());
        for ((&a, &b), &c) in r12.iter().zip(r33).zip(r34).rev() {
            for (name, v) in [("F12/F11", a), ("F33/F11", b), ("F34/F11", c)] {
                require(
                    name,
                    v,
                    v.is_finite() && v.abs() <= 1.0 + 1e-6,
                    "finite, in [-1, 1]",
                )?;
            }
            r.push([a, b, c].map(|v| v.clamp(-1.0, 1.0) as f32));
        }
        Ok(MuellerRatios { r })
    }

    /// F12/F11, F33/F11 and F34/F11 at each node (increasing μ).
    pub fn nodes(&self) -> &[[f32; 3]] {
        &self.r
    }

    /// The number of nodes.
    pub fn len(&self) -> usize {
        self.r.len()
    }

    /// Whether there are no nodes.
    pub fn is_empty(&self) -> bool {
        self.r.is_empty()
    }

    /// The ratios at a location of the table's nodes (`PhaseTable::locate`).
    #[inline]
    pub fn at(&self, (i, t): (usize, f64)) -> [f64; 3] {
        let (a, b) = (self.r[i], self.r[(i + 1).min(self.r.len() - 1)]);
        [0, 1, 2].map(|k| a[k] as f64 + t * (b[k] as f64 - a[k] as f64))
    }

    /// Heap bytes.
    pub fn bytes(&self) -> usize {
        self.r.capacity() * 12
    }
}

/// A bin's elements at table `table` (a tabulated wavelength) at a location of μ among its nodes
/// (`PhaseTable::locate`).
#[inline]
fn table_elements(b: &BinOptics, table: usize, at: (usize, f64)) -> Elements {
    let f = b.phase[table].eval_at(at);
    match b.mueller.get(table) {
        Some(r) => {
            let [a, c, d] = r.at(at);
            [f, f * a, f * c, f * d]
        }
        None => [f, 0.0, 0.0, 0.0],
    }
}

/// A bin's elements at the wavelength bracket `l` and μ = cos θ (as `phase::bin_phase` for F11); `at`:
/// μ located once among the nodes its tables share, where they do (else each table locates it).
#[inline]
fn bin_elements(
    b: &BinOptics,
    l: (usize, usize, f64),
    mu: f64,
    at: Option<(usize, f64)>,
) -> Elements {
    let located = |t: usize| at.unwrap_or_else(|| b.phase[t].locate(mu));
    let lo = table_elements(b, l.0, located(l.0));
    if l.2 == 0.0 {
        return lo;
    }
    let hi = table_elements(b, l.1, located(l.1));
    [0, 1, 2, 3].map(|k| (1.0 - l.2) * lo[k] + l.2 * hi[k])
}

impl DiscreteMedium {
    /// Whether the medium's bins carry Mueller ratios (`BinOptics::mueller`): its grains polarise.
    pub fn polarizes(&self) -> bool {
        self.bins.iter().any(|b| !b.mueller.is_empty())
    }

    /// The elements of a mixture per channel at μ = cos θ, and the pdf Σ_c π_c F11_c: F11 is
    /// `mixture_phase`'s value, the other elements weighed alike.
    pub(super) fn mixture_mueller(
        &self,
        m: &Mixture<impl Fn(u32) -> f64>,
        mu: f64,
        out: &mut [Elements],
    ) -> f64 {
        // Particle by particle (its bin looked up and μ located once), each channel's sums in the
        // members' order.
        let channels = m.ls.len();
        debug_assert!(channels <= MAX_CHANNELS && out.len() >= channels);
        let (mut num, mut den) = ([[0.0; 4]; MAX_CHANNELS], [0.0; MAX_CHANNELS]);
        for &j in m.members {
            let bin = self.optics.bin(j);
            let b = &self.bins[bin];
            let at = self.shared_nodes[bin].then(|| b.phase[0].locate(mu));
            let scale = (m.scale)(j);
            for (c, &l) in m.ls.iter().enumerate() {
                let w = scale * bin_albedo(b, l) * self.albedo_scale();
                if w > 0.0 {
                    let e = bin_elements(b, l, mu, at);
                    num[c].iter_mut().zip(e).for_each(|(n, x)| *n += w * x);
                    den[c] += w;
                }
            }
        }
        let mut pdf = 0.0;
        for c in 0..channels {
            out[c] = if den[c] > 0.0 {
                num[c].map(|x| x / den[c])
            } else {
                [0.0; 4]
            };
            pdf += m.pi[c] * out[c][0];
        }
        pdf
    }

    /// One lane's Mueller elements (one row per wavelength of `lam`, times the event's albedo with
    /// `scattered`), the pdf returned: `lane_phase_eval` with the polarised elements.
    pub(super) fn lane_phase_mueller(
        &self,
        events: &impl super::events::Events,
        lane: &PhaseEvalLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        out: &mut [Elements],
        scattered: bool,
    ) -> f64 {
        out.iter_mut().for_each(|x| *x = [0.0; 4]);
        let Some((e, mu)) = self.eval_event(events, lane) else {
            return 0.0;
        };
        let pi = event_channels(&e, lam.len());
        let mixture = self.event_mixture(&e, ls, &pi);
        let pdf = self.mixture_mueller(&mixture, mu, out);
        if scattered {
            let mut albedo = [1.0; MAX_CHANNELS];
            let channels = lam.len().min(MAX_CHANNELS);
            self.times_albedo(&e, lam, ls, &mut albedo[..channels]);
            for (row, a) in out.iter_mut().zip(albedo) {
                row.iter_mut().for_each(|x| *x *= a);
            }
        }
        pdf
    }
}

impl DiscreteMedium {
    /// The Mueller elements of the phase functions at each lane's `p` (batch interface, `phase_eval`'s
    /// polarised twin): (n × channels × 4 elements F11, F12, F33, F34, pdfs), without the albedo.
    pub fn phase_mueller(
        &self,
        lanes: &[PhaseEvalLane],
        lambda: &[f64],
        channels: usize,
    ) -> Result<(Vec<f64>, Vec<f64>), OpticsError> {
        use rayon::prelude::*;
        require(
            "channels",
            channels as f64,
            (1..=MAX_CHANNELS).contains(&channels),
            "1 to 4 (polarised variants)",
        )?;
        let events = self.events.read().unwrap();
        let res: Vec<([Elements; MAX_CHANNELS], f64)> = (0..lanes.len())
            .into_par_iter()
            .map(|i| {
                let lam = super::channels::lane_wavelengths(lambda, channels, i);
                let mut out = [[0.0; 4]; MAX_CHANNELS];
                let pdf = self.lane_phase_mueller(
                    &*events,
                    &lanes[i],
                    lam,
                    &self.brackets(lam),
                    &mut out[..channels],
                    false,
                );
                (out, pdf)
            })
            .collect();
        let pdf = res.iter().map(|r| r.1).collect();
        let values = res
            .iter()
            .flat_map(|r| r.0[..channels].iter().flatten().copied())
            .collect();
        Ok((values, pdf))
    }

    /// The packet interface's Mueller evaluation (`packet_phase_eval`'s polarised twin): per lane
    /// `channels` rows of the four elements (times the site's albedo) into `values`, and the pdf.
    /// `reuse`: a lane whose last evaluation had the same inputs gives that one again (the C++ plugin
    /// reads the elements of four channels in four calls); otherwise it is evaluated afresh.
    pub fn packet_phase_mueller(
        &self,
        lanes: &[Option<PhaseEvalLane>],
        lambda: &[f64],
        channels: usize,
        reuse: bool,
        values: &mut [Elements],
        pdf: &mut [f64],
    ) {
        use super::channels::PacketWaves;
        use super::lane::{at_site, same_direction};
        use super::packet_state::{MuellerLane, SampledLane};
        let channels = channels.min(MAX_CHANNELS);
        self.with_packet_state(|st| {
            let waves = PacketWaves::new(self, lambda, channels, &mut st.brackets);
            for (i, lane) in lanes.iter().enumerate().take(super::PACKET_LANES) {
                let v = &mut values[i * channels..(i + 1) * channels];
                v.iter_mut().for_each(|x| *x = [0.0; 4]);
                pdf[i] = 0.0;
                let Some(lane) = lane else {
                    st.mueller[i] = None;
                    continue;
                };
                let lane_waves = waves.lane(i);
                let wv = lane_waves.get();
                let inputs = SampledLane::inputs(lane.p, lane.wi, lane.wo);
                let lambda_bits = SampledLane::lambda(wv.lam);
                if let Some(c) = st.mueller[i]
                    .as_ref()
                    .filter(|c| reuse && c.inputs == inputs && c.lambda == lambda_bits)
                {
                    v.copy_from_slice(&c.values[..channels]);
                    pdf[i] = c.pdf;
                    continue;
                }
                self.settle(st, i, lane.p, &waves);
                // As `packet_phase_eval`: towards a light whose shadow ray was found blocked, zero.
                let widen = |p: [f32; 3]| p.map(|x| x as f64);
                let blocked = st.blocked[i].take().is_some_and(|(o, d, at)| {
                    at_site(lane.p, o)
                        && same_direction(d, lane.wo)
                        && st.enclosure.holds_segment(widen(o), widen(at))
                });
                if !blocked {
                    pdf[i] = self.lane_phase_mueller(&st.lane(i), lane, wv.lam, wv.ls, v, true);
                }
                let mut kept = [[0.0; 4]; MAX_CHANNELS];
                kept[..channels].copy_from_slice(v);
                st.mueller[i] = Some(MuellerLane {
                    inputs,
                    lambda: lambda_bits,
                    values: kept,
                    pdf: pdf[i],
                });
            }
        })
    }
}
