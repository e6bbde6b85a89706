//! A site's phase function (module docs of `crate::render::discrete`, "Phase function of a site"):
//! the mixture of its particles' tabulated phase functions per channel (Eq. 24), its evaluation and
//! its sampling, at a remembered event or at a site found from the geometry.

use super::channels::{channel_probabilities, event_channels, PerChannel};
use super::events::{key, normalised_throughput, Event, Events};
use super::{BinOptics, DiscreteMedium, PhaseEvalLane, PhaseSampleLane, MAX_CHANNELS};
use crate::render::phase_lanes::PhaseLanes;
use crate::space::grid::Site;
use crate::space::ray::RaySegment;
use crate::space::vec3::{deflect, normalise};
use std::borrow::Cow;

/// A bin's albedo at the wavelength bracket `l` (without the medium's albedo scale).
#[inline(always)]
pub(super) fn bin_albedo(b: &BinOptics, l: (usize, usize, f64)) -> f64 {
    (1.0 - l.2) * b.albedo[l.0] + l.2 * b.albedo[l.1]
}

/// A bin's phase function at the wavelength bracket `l` and μ = cos θ.
#[inline(always)]
fn bin_phase(b: &BinOptics, l: (usize, usize, f64), mu: f64) -> f64 {
    let lo = b.phase[l.0].eval(mu);
    if l.2 == 0.0 {
        lo
    } else {
        (1.0 - l.2) * lo + l.2 * b.phase[l.1].eval(mu)
    }
}

/// [`bin_phase`] at a location of μ in the bin's tables, all on the same nodes (`PhaseTable::locate`).
#[inline(always)]
fn bin_phase_at(b: &BinOptics, l: (usize, usize, f64), at: (usize, f64)) -> f64 {
    let lo = b.phase[l.0].eval_at(at);
    if l.2 == 0.0 {
        lo
    } else {
        (1.0 - l.2) * lo + l.2 * b.phase[l.1].eval_at(at)
    }
}

/// A mixture of particles as a phase function sees it (`discrete` docs): particle j of `members` weighs
/// `scale(j)` × its albedo in each channel; `ls` are the channels' wavelength brackets (from
/// `DiscreteMedium::bracket`) and `pi` the probabilities of sampling each channel.
pub(super) struct Mixture<'a, S> {
    pub(super) members: &'a [u32],
    pub(super) scale: S,
    pub(super) ls: &'a [(usize, usize, f64)],
    pub(super) pi: &'a [f64],
}

/// A sampled direction, its weights per channel (value / pdf) and pdf.
pub(super) type Sample = ([f64; 3], PerChannel<f64>, f64);

/// No direction: zero weights and pdf.
pub(super) fn null_sample(channels: usize) -> Sample {
    ([0.0, 0.0, 1.0], PerChannel::from_fn(channels, |_| 0.0), 0.0)
}

/// Per-lane samples as flat columns (directions, weights lane-major, pdfs).
pub(super) fn unzip_samples(res: Vec<Sample>) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
    let wo = res.iter().map(|r| r.0).collect();
    let pdf = res.iter().map(|r| r.2).collect();
    (
        wo,
        res.iter().flat_map(|r| r.1.iter().copied()).collect(),
        pdf,
    )
}

impl DiscreteMedium {
    /// A particle's albedo at the wavelength bracket `l`, times the medium's albedo scale.
    pub(super) fn albedo_at(&self, particle: u32, l: (usize, usize, f64)) -> f64 {
        bin_albedo(&self.bins[self.optics.bin(particle)], l) * self.albedo_scale()
    }

    /// A particle's phase function at the wavelength bracket `l` and μ = cos θ.
    fn phase_at(&self, particle: u32, l: (usize, usize, f64), mu: f64) -> f64 {
        bin_phase(&self.bins[self.optics.bin(particle)], l, mu)
    }

    /// `v` (one value per channel of `lam`, brackets `ls`) times the event's albedo: the one remembered
    /// with it where it was remembered at these wavelengths, else the site's.
    pub(super) fn times_albedo(
        &self,
        e: &Event,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        v: &mut [f64],
    ) {
        let known =
            lam.len() <= MAX_CHANNELS && lam.first().map(|&l| l as f32) == Some(e.albedo_nm);
        for (c, x) in v.iter_mut().enumerate() {
            *x *= if known {
                e.albedo[c] as f64
            } else {
                self.site_albedo(&e.site, ls[c])
            };
        }
    }

    /// τ-weighted albedo of a site at one wavelength.
    pub(super) fn site_albedo(&self, s: &Site, l: (usize, usize, f64)) -> f64 {
        if let [j] = s.members() {
            // One particle (most sites): its own albedo, no weights to divide out.
            return self.albedo_at(*j, l);
        }
        let (mut num, mut den) = (0.0, 0.0);
        for &j in s.members() {
            let t = self.optics.tau(j);
            num += t * self.albedo_at(j, l);
            den += t;
        }
        if den > 0.0 {
            num / den
        } else {
            0.0
        }
    }

    /// The site at `p` found from the geometry when the event is not remembered: the particles whose
    /// projection on the ray through `p` along `w_in` lies within a few float32 ulps of `p`.
    pub(super) fn site_near(&self, p: [f32; 3], w_in: [f64; 3]) -> Option<Site> {
        let o = p.map(|x| x as f64);
        let tol = 4.0 * self.coincide + 1e-6 * o.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        let mut site = Site::default();
        if let Some(g) = &self.grid {
            g.walk(&RaySegment::new(o, w_in, -tol, tol), |t, i, key| {
                if site.len == 0 {
                    site.t = t;
                }
                if (site.len as usize) < Site::CAPACITY {
                    site.keys[site.len as usize] = key;
                }
                site.push(i);
                true
            });
        }
        // An interaction in the continuous field is at no particle's projection: its cell's particles
        // (up to the site's capacity) stand in for the one picked there.
        if let (0, Some(f)) = (site.len, &self.field) {
            if let Some(c) = f.cell_at(o) {
                f.members(c).for_each(|i| site.push(i));
            }
        }
        (site.len > 0).then_some(site)
    }

    /// Phase function of a mixture of particles per channel at μ = cos θ, and the pdf Σ_c π_c f_c of
    /// sampling it (`discrete` docs; see [`Mixture`]).
    pub(super) fn mixture_phase(
        &self,
        m: &Mixture<impl Fn(u32) -> f64>,
        mu: f64,
        values: &mut [f64],
    ) -> f64 {
        self.mixture_phase_at(m, mu, None, values)
    }

    /// [`Self::mixture_phase`] with μ's location in the tables of the one particle's bin where the
    /// caller knows it (`at`: a sample from one of them, `PhaseTable::sample_located`).
    fn mixture_phase_at(
        &self,
        m: &Mixture<impl Fn(u32) -> f64>,
        mu: f64,
        at: Option<(usize, f64)>,
        values: &mut [f64],
    ) -> f64 {
        let mut pdf = 0.0;
        if let [j] = m.members {
            // One particle (most events): its own phase function in every channel where it scatters,
            // its bin looked up once (the weights below cancel), μ located
            // once for all its tables where they share their nodes (or not at all where a sample from
            // them told where it lies).
            let bin = self.optics.bin(*j);
            let (b, w) = (&self.bins[bin], (m.scale)(*j) * self.albedo_scale());
            let at = self.shared_nodes[bin].then(|| at.unwrap_or_else(|| b.phase[0].locate(mu)));
            for (c, &l) in m.ls.iter().enumerate() {
                values[c] = match (w * bin_albedo(b, l) > 0.0, at) {
                    (false, _) => 0.0,
                    (true, Some(at)) => bin_phase_at(b, l, at),
                    (true, None) => bin_phase(b, l, mu),
                };
                pdf += m.pi[c] * values[c];
            }
            return pdf;
        }
        for (c, &l) in m.ls.iter().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for &j in m.members {
                let w = (m.scale)(j) * self.albedo_at(j, l);
                num += w * self.phase_at(j, l, mu);
                den += w;
            }
            values[c] = if den > 0.0 { num / den } else { 0.0 };
            pdf += m.pi[c] * values[c];
        }
        pdf
    }

    /// Sample a mixture (see [`Self::mixture_phase`]) around the propagation direction `w_in`: a channel
    /// with probability π_c, then a particle by its weight in that channel, then its table (lower/upper
    /// wavelength), each by rescaling `u1`; `u2` draws the direction. Returns (wo, weight per
    /// channel = value / pdf, pdf), or the null sample.
    pub(super) fn mixture_sample(
        &self,
        m: &Mixture<impl Fn(u32) -> f64>,
        w_in: [f64; 3],
        u1: f64,
        u2: [f64; 2],
    ) -> Sample {
        let Mixture {
            members,
            scale,
            ls,
            pi,
        } = m;
        let mut u = u1.clamp(0.0, 1.0 - f64::EPSILON);
        let mut c = ls.len() - 1;
        let mut acc = 0.0;
        for (k, &p) in pi.iter().enumerate().take(ls.len()) {
            if u < acc + p && p > 0.0 {
                c = k;
                u = ((u - acc) / p).clamp(0.0, 1.0 - f64::EPSILON);
                break;
            }
            acc += p;
        }
        let l = ls[c];
        // Weights computed twice (the total, then the pick) rather than stored: no allocation per sample.
        let weight = |j: u32| scale(j) * self.albedo_at(j, l);
        let j = if let [j] = members {
            // One particle: no pick (u is left as it is).
            if !(weight(*j) > 0.0) {
                return null_sample(ls.len());
            }
            *j
        } else {
            let total: f64 = members.iter().map(|&j| weight(j)).sum();
            if !(total > 0.0) {
                return null_sample(ls.len());
            }
            let mut pick = members.len() - 1;
            let mut acc = 0.0;
            for (k, w) in members.iter().map(|&j| weight(j)).enumerate() {
                if u * total < acc + w {
                    pick = k;
                    u = ((u * total - acc) / w).clamp(0.0, 1.0 - f64::EPSILON);
                    break;
                }
                acc += w;
            }
            members[pick]
        };
        let table = if u < 1.0 - l.2 { l.0 } else { l.1 };
        let (mu, at) = self.bins[self.optics.bin(j)].phase[table].sample_located(u2[0]);
        let wo = deflect(w_in, mu, u2[1]);
        let mut v = PerChannel::from_fn(ls.len(), |_| 0.0);
        let pdf = self.mixture_phase_at(m, mu, Some(at), &mut v);
        if pdf > 0.0 {
            let inv = 1.0 / pdf;
            v.iter_mut().for_each(|x| *x *= inv);
            (wo, v, pdf)
        } else {
            null_sample(ls.len())
        }
    }

    /// One lane of [`Self::phase_eval`]: the values into `v` (one per wavelength of `lam`; times the
    /// event's albedo with `scattered`), the pdf returned.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn lane_phase_eval(
        &self,
        events: &impl Events,
        lane: &PhaseEvalLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        v: &mut [f64],
        scattered: bool,
    ) -> f64 {
        v.iter_mut().for_each(|x| *x = 0.0);
        let Some((e, mu)) = self.eval_event(events, lane) else {
            return 0.0;
        };
        let pi = event_channels(&e, lam.len());
        let mixture = self.event_mixture(&e, ls, &pi);
        let pdf = self.mixture_phase(&mixture, mu, v);
        if scattered {
            self.times_albedo(&e, lam, ls, v);
        }
        pdf
    }

    /// The event an evaluation lane is at and μ = cos θ between its directions (None: a direction of no
    /// length, or no event there).
    pub(super) fn eval_event<'e>(
        &self,
        events: &'e impl Events,
        lane: &PhaseEvalLane,
    ) -> Option<(Cow<'e, Event>, f64)> {
        let w_in = normalise(lane.wi.map(|x| -(x as f64)))?;
        let w_out = normalise(lane.wo.map(|x| x as f64))?;
        let e = self.event_or_geometry(events, lane.p, w_in)?;
        let mu = (w_in[0] * w_out[0] + w_in[1] * w_out[1] + w_in[2] * w_out[2]).clamp(-1.0, 1.0);
        Some((e, mu))
    }

    /// One lane of [`Self::phase_sample`]: the sample (its weights times the event's albedo with
    /// `scattered`) and the path's throughput after it (to store as the event's `t_out`; the albedo is
    /// in its `t_in` already).
    pub(super) fn lane_phase_sample(
        &self,
        events: &impl Events,
        lane: &PhaseSampleLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        scattered: bool,
    ) -> (Sample, Option<[f32; MAX_CHANNELS]>) {
        match self.sample_event(events, lane) {
            Some((w_in, e)) => self.event_phase_sample(&e, w_in, lane, lam, ls, scattered),
            None => (null_sample(lam.len()), None),
        }
    }

    /// A phase sample's incident direction (the path's, reversed back) and its event (None: no
    /// direction, or no event there).
    pub(super) fn sample_event<'e>(
        &self,
        events: &'e impl Events,
        lane: &PhaseSampleLane,
    ) -> Option<([f64; 3], Cow<'e, Event>)> {
        let w_in = normalise(lane.wi.map(|x| -(x as f64)))?;
        Some((w_in, self.event_or_geometry(events, lane.p, w_in)?))
    }

    /// [`Self::lane_phase_sample`] at the lane's event `e`, the path arriving along `w_in`.
    pub(super) fn event_phase_sample(
        &self,
        e: &Event,
        w_in: [f64; 3],
        lane: &PhaseSampleLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        scattered: bool,
    ) -> (Sample, Option<[f32; MAX_CHANNELS]>) {
        let channels = lam.len();
        let pi = event_channels(e, channels);
        let mixture = self.event_mixture(e, ls, &pi);
        let mut sample = self.mixture_sample(&mixture, w_in, lane.u1, lane.u2);
        // The path's throughput after this bounce, t_c f_c / q ∝ t_c × weight_c (`discrete` docs).
        let known = e.t_in.iter().any(|&x| x > 0.0);
        let t_out = (channels <= MAX_CHANNELS && sample.2 > 0.0).then(|| {
            normalised_throughput(
                (0..channels).map(|c| if known { e.t_in[c] as f64 } else { 1.0 } * sample.1[c]),
            )
        });
        if scattered {
            self.times_albedo(e, lam, ls, &mut sample.1);
        }
        (sample, t_out)
    }

    /// Slot `k` of `lanes` ([`PhaseLanes`]) for lane `lane`'s sample at its event `e`, where the event
    /// is one particle whose tables share their nodes and the wavelengths `ls` are tabulated ones
    /// (checked by the caller); false where it is not one particle with shared nodes.
    pub(super) fn fill_phase_lane(
        &self,
        e: &Event,
        lane: &PhaseSampleLane,
        lam: &[f64],
        ls: &[(usize, usize, f64)],
        lanes: &mut PhaseLanes,
        k: usize,
    ) -> bool {
        let [j] = e.site.members() else {
            return false;
        };
        let bin = self.optics.bin(*j);
        if !self.shared_nodes[bin] {
            return false;
        }
        let channels = lam.len();
        let (b, tau, scale) = (&self.bins[bin], self.optics.tau(*j), self.albedo_scale());
        let pi = channel_probabilities(&e.t_in, channels);
        let known = e.t_in.iter().any(|&x| x > 0.0);
        let mut albedo = [1.0; MAX_CHANNELS];
        self.times_albedo(e, lam, ls, &mut albedo[..channels]);
        for c in 0..MAX_CHANNELS {
            let l = ls[c.min(channels - 1)];
            lanes.set_table(c, k, b.phase[l.0].sampling_view());
            if c < channels {
                // As `mixture_sample` (the pick) and `mixture_phase_at` (the values) weigh them.
                let a = bin_albedo(b, l);
                lanes.pi[c][k] = pi[c];
                lanes.pickable[c][k] = (tau * (a * scale) > 0.0) as u64;
                lanes.scatters[c][k] = (tau * scale * a > 0.0) as u64;
                lanes.t_in[c][k] = if known { e.t_in[c] as f64 } else { 1.0 };
                lanes.albedo[c][k] = albedo[c];
            } else {
                lanes.pi[c][k] = 0.0;
                lanes.pickable[c][k] = 0;
                lanes.scatters[c][k] = 0;
            }
        }
        (lanes.u1[k], lanes.u2[k]) = (lane.u1, lane.u2[0]);
        true
    }

    /// The mixture of an event's particles, each weighing its τ (`discrete` docs), at the channels'
    /// wavelength brackets `ls`, sampled with channel probabilities `pi`.
    pub(super) fn event_mixture<'a>(
        &'a self,
        e: &'a Event,
        ls: &'a [(usize, usize, f64)],
        pi: &'a [f64],
    ) -> Mixture<'a, impl Fn(u32) -> f64 + 'a> {
        Mixture {
            members: e.site.members(),
            scale: |j| self.optics.tau(j),
            ls,
            pi,
        }
    }

    /// The remembered event at `p`, or else the site found from the geometry (uniform channels).
    pub(super) fn event_or_geometry<'e>(
        &self,
        events: &'e impl Events,
        p: [f32; 3],
        w_in: [f64; 3],
    ) -> Option<Cow<'e, Event>> {
        match events.event(&key(p)) {
            Some(e) => Some(Cow::Borrowed(e)),
            None => self.site_near(p, w_in).map(|site| {
                Cow::Owned(Event {
                    site,
                    ..Event::default()
                })
            }),
        }
    }
}
