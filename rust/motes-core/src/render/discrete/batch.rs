//! The batch interface (Dr.Jit's evaluated mode, where a wavefront's kernels may run a path's calls
//! on different threads): free flights of many rays at once whose events the renderer then commits
//! ([`DiscreteMedium::commit_events`]) into the medium's shared event map, and the phase functions of
//! those events.

use super::channels::lane_wavelengths;
use super::counters::SurfaceTally;
use super::events::{event_after, key, Event, Parent};
use super::flight::ray_bits;
use super::phase::{unzip_samples, Sample};
use super::{DiscreteMedium, PhaseEvalLane, PhaseSampleLane, SiteSample, MAX_CHANNELS};
use crate::error::{require, OpticsError};
use crate::rng::uniform;
use crate::space::grid::Site;
use rayon::prelude::*;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// A lane of the last `sample_sites` call awaiting `commit_events`: its site, whether to remember it,
/// and the channel throughput of the event its ray started at (zeros: none).
pub(super) type Pending = (Option<Site>, bool, Parent);

impl DiscreteMedium {
    /// Sample the next site along each ray (origin `o`, direction `d`, on (0, t_max)), skipping the
    /// particles of the event the ray starts at. The sites are kept for [`Self::commit_events`], which
    /// remembers the events of the lanes marked in `remember` (those whose events start new rays; an
    /// event ends a shadow ray, so shadow rays need not be remembered).
    pub fn sample_sites(
        &self,
        o: &[[f32; 3]],
        d: &[[f32; 3]],
        t_max: &[f64],
        remember: &[bool],
    ) -> Vec<SiteSample> {
        let call = self.calls.fetch_add(1, Ordering::Relaxed);
        let events = self.events.read().unwrap();
        let view = Arc::clone(&self.view.read().unwrap());
        let res: Vec<(Option<Site>, f64, Parent)> = o
            .par_iter()
            .zip(d.par_iter().zip(t_max.par_iter()))
            .enumerate()
            .map(|(lane, (oo, (dd, &tm)))| {
                // Counter and ray bits: distinct for every lane and call (and for concurrent callers).
                let u = uniform(self.seed ^ ray_bits(oo, dd), call, lane as u64);
                let mut surface = SurfaceTally::default();
                let plan =
                    self.lane_plan(&*events, &view, &mut surface, *oo, *dd, tm, u, true, None);
                let r = self.fly(plan, true);
                if surface.checked > 0 {
                    self.surface_counts.add(surface.checked, surface.saw_field);
                }
                r
            })
            .collect();
        drop(events);
        let out = res
            .iter()
            .map(|(s, tau, _)| SiteSample {
                t: s.map(|s| s.t),
                tau_before: *tau,
            })
            .collect();
        let pending = res
            .into_iter()
            .zip(remember)
            .map(|(r, &keep)| (r.0, keep, r.2))
            .collect();
        self.pending
            .lock()
            .unwrap()
            .insert(std::thread::current().id(), pending);
        out
    }

    /// Record the events of this thread's last [`Self::sample_sites`] call at the positions the renderer placed
    /// them (`p`, one per lane of that call; `active` false for lanes without an event) and return each
    /// lane's albedo at its channel wavelengths (`lambda`: `channels` per lane, or `channels` shared).
    pub fn commit_events(
        &self,
        p: &[[f32; 3]],
        active: &[bool],
        lambda: &[f64],
        channels: usize,
    ) -> Result<Vec<f64>, OpticsError> {
        let pending = self
            .pending
            .lock()
            .unwrap()
            .remove(&std::thread::current().id())
            .unwrap_or_default();
        let n = p.len();
        require(
            "lanes (must equal the last sample_sites call)",
            n as f64,
            pending.len() == n && active.len() == n,
            "the same lane count",
        )?;
        require(
            "lambda (length)",
            lambda.len() as f64,
            lambda.len() == channels || lambda.len() == n * channels,
            "channels or lanes × channels",
        )?;
        let albedo: Vec<f64> = (0..n)
            .into_par_iter()
            .flat_map_iter(|i| {
                let site = if active[i] { pending[i].0 } else { None };
                let lam = lane_wavelengths(lambda, channels, i);
                (0..channels)
                    .map(move |c| site.map_or(0.0, |s| self.site_albedo(&s, self.bracket(lam[c]))))
            })
            .collect();
        let mut events = self.events.write().unwrap();
        events.capacity = events.capacity.max(4 * n);
        for i in 0..n {
            if let (true, (Some(site), true, parent)) = (active[i], pending[i]) {
                events.insert(
                    key(p[i]),
                    event_after(
                        site,
                        &parent,
                        &albedo[i * channels..(i + 1) * channels],
                        lane_wavelengths(lambda, channels, i),
                    ),
                );
            }
        }
        Ok(albedo)
    }

    /// The site of an event position, if it is remembered.
    pub fn event_at(&self, p: [f32; 3]) -> Option<Site> {
        self.events.read().unwrap().get(&key(p)).map(|e| e.site)
    }

    /// Remember an event directly (tests and tools: e.g. a chi-square test of a chosen mixture).
    pub fn insert_event(&self, p: [f32; 3], particles: &[u32]) -> Result<(), OpticsError> {
        let mut s = Site::default();
        for &i in particles {
            require(
                "particle",
                i as f64,
                (i as usize) < self.optics.ids(),
                "< number of particles walked one by one (compact storage: by position)",
            )?;
            s.push(i);
        }
        require(
            "particles (count)",
            particles.len() as f64,
            !particles.is_empty(),
            ">= 1",
        )?;
        self.events_anywhere.store(true, Ordering::Relaxed);
        self.events.write().unwrap().insert(
            key(p),
            Event {
                site: s,
                ..Event::default()
            },
        );
        Ok(())
    }

    /// Evaluate the phase function of the event at each lane's `p` for its incident and outgoing
    /// directions: per-channel values (1/sr) and the pdf. Positions without a remembered event give 0
    /// and 0.
    pub fn phase_eval(
        &self,
        lanes: &[PhaseEvalLane],
        lambda: &[f64],
        channels: usize,
    ) -> (Vec<f64>, Vec<f64>) {
        let events = self.events.read().unwrap();
        let res: Vec<(Vec<f64>, f64)> = (0..lanes.len())
            .into_par_iter()
            .map(|i| {
                let lam = lane_wavelengths(lambda, channels, i);
                let mut v = vec![0.0; channels];
                let pdf = self.lane_phase_eval(
                    &*events,
                    &lanes[i],
                    lam,
                    &self.brackets(lam),
                    &mut v,
                    false,
                );
                (v, pdf)
            })
            .collect();
        let pdf = res.iter().map(|r| r.1).collect();
        (res.into_iter().flat_map(|r| r.0).collect(), pdf)
    }

    /// Sample the phase function of the event at each lane's `p` (`discrete` docs): outgoing directions,
    /// weights (value / pdf per channel) and pdfs.
    pub fn phase_sample(
        &self,
        lanes: &[PhaseSampleLane],
        lambda: &[f64],
        channels: usize,
    ) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f64>) {
        let events = self.events.read().unwrap();
        let res: Vec<(Sample, Option<[f32; MAX_CHANNELS]>)> = (0..lanes.len())
            .into_par_iter()
            .map(|i| {
                let lam = lane_wavelengths(lambda, channels, i);
                self.lane_phase_sample(&*events, &lanes[i], lam, &self.brackets(lam), false)
            })
            .collect();
        drop(events);
        let mut events = self.events.write().unwrap();
        for (lane, (_, t_out)) in lanes.iter().zip(&res) {
            if let (Some(t), Some(e)) = (t_out, events.get_mut(&key(lane.p))) {
                e.t_out = *t;
            }
        }
        drop(events);
        unzip_samples(res.into_iter().map(|r| r.0).collect())
    }
}
