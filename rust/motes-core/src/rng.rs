//! Counter-based random numbers: the SplitMix64 output function (Steele, Lea & Flood, "Fast
//! splittable pseudorandom number generators", OOPSLA 2014). One home for the hash behind the free
//! flights' uniform numbers (`render::discrete`, [`uniform`]) and the procedural densities' lattice
//! values (Python's `motes.Noise`, through the binding).
//!
//! Infrastructure: implements no equation of the paper.

/// The golden-ratio increment of SplitMix64's state, 2^64 / φ rounded to odd.
pub const GOLDEN_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// SplitMix64's finaliser: a bijection of 64 bits in which every input bit flips each output bit
/// with probability close to 1/2.
#[inline(always)]
pub fn splitmix64_finalise(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The odd constant that spreads a stream's index over the state ([`stream_bits`]).
pub const STREAM_GAMMA: u64 = 0xD1B5_4A32_D192_ED03;

/// The `index`-th 64 random bits of the stream `key`: SplitMix64's finaliser of the key and the index
/// spread by [`STREAM_GAMMA`]. Counter-based, so that the draws of many streams at one index can be
/// computed side by side (a packet's free flights, `render::continuous`).
#[inline(always)]
pub fn stream_bits(key: u64, index: u64) -> u64 {
    splitmix64_finalise(key ^ index.wrapping_mul(STREAM_GAMMA))
}

/// SplitMix64's output for state `z`: the state advanced by [`GOLDEN_GAMMA`], then finalised.
#[inline]
pub fn splitmix64(z: u64) -> u64 {
    splitmix64_finalise(z.wrapping_add(GOLDEN_GAMMA))
}

/// A uniform number in [0, 1) from the top 53 bits of `z`.
#[inline]
pub fn unit_f64(z: u64) -> f64 {
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// The stream of call `call` under `seed`: the key whose [`stream_bits`] by index are [`random_bits`].
#[inline]
pub fn stream_key(seed: u64, call: u64) -> u64 {
    seed ^ call.wrapping_mul(GOLDEN_GAMMA)
}

/// The 64 random bits of (seed, call, lane): the `lane`-th of call `call`'s stream under `seed`.
#[inline]
pub fn random_bits(seed: u64, call: u64, lane: u64) -> u64 {
    stream_bits(stream_key(seed, call), lane)
}

/// A uniform number in [0, 1) from (seed, call, lane) ([`random_bits`]): counter-based, so that what
/// a render draws does not depend on the thread schedule.
#[inline]
pub fn uniform(seed: u64, call: u64, lane: u64) -> f64 {
    unit_f64(random_bits(seed, call, lane))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The published SplitMix64 sequence from seed 0 (the state advances by GOLDEN_GAMMA per output).
    #[test]
    fn matches_the_reference_sequence() {
        let outputs: Vec<u64> = (0..3u64)
            .map(|k| splitmix64(k.wrapping_mul(GOLDEN_GAMMA)))
            .collect();
        assert_eq!(
            outputs,
            [
                0xE220_A839_7B1D_CDAF,
                0x6E78_9E6A_A1B9_65F4,
                0x06C4_5D18_8009_454F
            ]
        );
    }
}
