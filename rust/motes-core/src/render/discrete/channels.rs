//! Colour channels: per-channel values without allocation, the wavelengths of a call's lanes and
//! their brackets in the tabulated wavelengths, and the throughput-proportional channel choice
//! (module docs of `crate::render::discrete`, "Colour weights along a path").

use super::events::Event;
use super::{DiscreteMedium, DEFENSIVE_MIX, MAX_CHANNELS};

/// Channel choice probabilities π from a throughput (zeros: uniform), `channels` of them.
#[inline]
pub(super) fn channel_probabilities(
    t: &[f32; MAX_CHANNELS],
    channels: usize,
) -> [f64; MAX_CHANNELS] {
    let mut pi = [0.0; MAX_CHANNELS];
    let c = channels.min(MAX_CHANNELS);
    let total: f64 = t[..c].iter().map(|&x| x as f64).sum();
    let uniform = 1.0 / c as f64;
    // One division, not one per channel (these are per-event work).
    let inv = if total > 0.0 && total.is_finite() {
        1.0 / total
    } else {
        0.0
    };
    for k in 0..c {
        let share = if inv > 0.0 {
            t[k] as f64 * inv
        } else {
            uniform
        };
        pi[k] = (1.0 - DEFENSIVE_MIX) * share + DEFENSIVE_MIX * uniform;
    }
    pi
}

/// Lane `i`'s wavelengths in `lambda`: all of it when its `channels` wavelengths are shared by
/// every lane, else the lane's own `channels` of them.
#[inline]
pub(super) fn lane_wavelengths(lambda: &[f64], channels: usize, i: usize) -> &[f64] {
    if lambda.len() == channels {
        lambda
    } else {
        &lambda[i * channels..(i + 1) * channels]
    }
}

/// Per-channel values of one lane: up to [`MAX_CHANNELS`] inline, more on the heap, so that a lane's
/// phase-function work allocates nothing in the RGB and spectral variants.
#[derive(Clone, Debug)]
pub(super) enum PerChannel<T> {
    Inline([T; MAX_CHANNELS], usize),
    Heap(Vec<T>),
}

impl<T: Copy + Default> PerChannel<T> {
    pub(super) fn from_fn(n: usize, mut f: impl FnMut(usize) -> T) -> Self {
        if n <= MAX_CHANNELS {
            let mut a = [T::default(); MAX_CHANNELS];
            a.iter_mut()
                .take(n)
                .enumerate()
                .for_each(|(c, x)| *x = f(c));
            PerChannel::Inline(a, n)
        } else {
            PerChannel::Heap((0..n).map(f).collect())
        }
    }
}

impl<T> std::ops::Deref for PerChannel<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match self {
            PerChannel::Inline(a, n) => &a[..*n],
            PerChannel::Heap(v) => v,
        }
    }
}

impl<T> std::ops::DerefMut for PerChannel<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match self {
            PerChannel::Inline(a, n) => &mut a[..*n],
            PerChannel::Heap(v) => v,
        }
    }
}

/// Uniform channel choice.
pub(super) fn uniform_channels(channels: usize) -> PerChannel<f64> {
    PerChannel::from_fn(channels, |_| 1.0 / channels as f64)
}

/// The channel choice of an event for `channels` channels (uniform beyond [`MAX_CHANNELS`]).
pub(super) fn event_channels(e: &Event, channels: usize) -> PerChannel<f64> {
    if channels > MAX_CHANNELS {
        return uniform_channels(channels);
    }
    let pi = channel_probabilities(&e.t_in, channels);
    PerChannel::from_fn(channels, |c| pi[c])
}

/// `dst.copy_from_slice(src)` for a lane's channels, a few moves where there are at most
/// [`MAX_CHANNELS`] (`copy_from_slice` of a length known only at run time is a call to `memcpy`, per
/// lane per call).
#[inline(always)]
pub(super) fn copy_channels(dst: &mut [f64], src: &[f64]) {
    debug_assert_eq!(dst.len(), src.len());
    match dst.len() {
        1 => dst[..1].copy_from_slice(&src[..1]),
        2 => dst[..2].copy_from_slice(&src[..2]),
        3 => dst[..3].copy_from_slice(&src[..3]),
        4 => dst[..4].copy_from_slice(&src[..4]),
        _ => dst.copy_from_slice(src),
    }
}

/// A lane's wavelengths and their tables' brackets ([`DiscreteMedium::bracket`]).
#[derive(Clone, Copy)]
pub(super) struct Waves<'a> {
    pub(super) lam: &'a [f64],
    pub(super) ls: &'a [(usize, usize, f64)],
}

/// A packet call's wavelengths: `channels` shared by every lane (their brackets found once per call:
/// RGB variants) or `channels` per lane.
pub(super) struct PacketWaves<'a> {
    pub(super) m: &'a DiscreteMedium,
    pub(super) lambda: &'a [f64],
    pub(super) channels: usize,
    pub(super) shared: Option<PerChannel<(usize, usize, f64)>>,
}

impl<'a> PacketWaves<'a> {
    /// The wavelengths of a call (`last`: the thread's brackets of the last shared ones).
    pub(super) fn new(
        m: &'a DiscreteMedium,
        lambda: &'a [f64],
        channels: usize,
        last: &mut LastBrackets,
    ) -> Self {
        let shared = (lambda.len() == channels).then(|| m.brackets_cached(lambda, last));
        PacketWaves {
            m,
            lambda,
            channels,
            shared,
        }
    }

    /// Lane `i`'s wavelengths (`.get()` borrows them as [`Waves`]).
    pub(super) fn lane(&self, i: usize) -> LaneWaves<'_> {
        let lam = lane_wavelengths(self.lambda, self.channels, i);
        LaneWaves {
            lam,
            own: self.shared.is_none().then(|| self.m.brackets(lam)),
            shared: &self.shared,
        }
    }
}

/// The last shared wavelengths' bits and count, and their brackets ([`DiscreteMedium::brackets_cached`]).
pub(super) type LastBrackets = Option<(
    [u64; MAX_CHANNELS],
    usize,
    [(usize, usize, f64); MAX_CHANNELS],
)>;

/// One lane's wavelengths from [`PacketWaves::lane`].
pub(super) struct LaneWaves<'a> {
    pub(super) lam: &'a [f64],
    pub(super) own: Option<PerChannel<(usize, usize, f64)>>,
    pub(super) shared: &'a Option<PerChannel<(usize, usize, f64)>>,
}

impl LaneWaves<'_> {
    pub(super) fn get(&self) -> Waves<'_> {
        Waves {
            lam: self.lam,
            ls: self
                .own
                .as_deref()
                .or(self.shared.as_deref())
                .expect("brackets, shared or the lane's own"),
        }
    }
}

impl DiscreteMedium {
    /// The [`Self::bracket`] of each wavelength of `lam`.
    pub(super) fn brackets(&self, lam: &[f64]) -> PerChannel<(usize, usize, f64)> {
        PerChannel::from_fn(lam.len(), |c| self.bracket(lam[c]))
    }

    /// [`Self::brackets`] of the wavelengths a packet's lanes share, kept in the thread's packet state
    /// for the last wavelengths asked (an RGB render asks for the same three in every call; a
    /// thread-local of its own would cost a TLS lookup per call).
    fn brackets_cached(
        &self,
        lam: &[f64],
        last: &mut LastBrackets,
    ) -> PerChannel<(usize, usize, f64)> {
        if lam.len() > MAX_CHANNELS {
            return self.brackets(lam);
        }
        let mut bits = [0u64; MAX_CHANNELS];
        bits.iter_mut().zip(lam).for_each(|(b, l)| *b = l.to_bits());
        if let Some((k, n, ls)) = last {
            if *k == bits && *n == lam.len() {
                return PerChannel::Inline(*ls, lam.len());
            }
        }
        let ls = self.brackets(lam);
        let mut flat = [(0, 0, 0.0); MAX_CHANNELS];
        flat.iter_mut().zip(ls.iter()).for_each(|(f, l)| *f = *l);
        *last = Some((bits, lam.len(), flat));
        ls
    }

    /// Interpolation of the tables at wavelength `l`: (lower index, upper index, weight of the upper);
    /// clamped to the tabulated range.
    pub(super) fn bracket(&self, l: f64) -> (usize, usize, f64) {
        let k = self.lambda.partition_point(|&x| x <= l);
        if k == 0 {
            (0, 0, 0.0)
        } else if k >= self.lambda.len() {
            let m = self.lambda.len() - 1;
            (m, m, 0.0)
        } else {
            let (a, b) = (self.lambda[k - 1], self.lambda[k]);
            (k - 1, k, (l - a) / (b - a))
        }
    }
}
