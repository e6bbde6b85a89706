//! Statistics counters that render threads add to without sharing a cache line.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

/// Counter shards: more than the render threads of most machines (threads beyond share shards, still
/// exactly).
const COUNT_SHARDS: usize = 16;

/// One shard of [`ShardedCounts`], alone on its cache lines.
#[derive(Default)]
#[repr(align(128))]
struct CountShard([AtomicU64; 2]);

/// Two statistics counters (rays, interactions) that render threads add to without sharing a cache
/// line: one shared atomic per counter would move its line between the cores once per packet.
#[derive(Default)]
pub(super) struct ShardedCounts([CountShard; COUNT_SHARDS]);

impl ShardedCounts {
    pub(super) fn add(&self, a: u64, b: u64) {
        self.add_to(COUNT_SHARD.with(|s| *s), a, b)
    }
    /// [`Self::add`] to shard `shard` (a packet state's own: no thread-local lookup per packet).
    pub(super) fn add_to(&self, shard: usize, a: u64, b: u64) {
        let shard = &self.0[shard % COUNT_SHARDS].0;
        shard[0].fetch_add(a, Ordering::Relaxed);
        shard[1].fetch_add(b, Ordering::Relaxed);
    }
    pub(super) fn totals(&self) -> (u64, u64) {
        let sum = |k: usize| self.0.iter().map(|s| s.0[k].load(Ordering::Relaxed)).sum();
        (sum(0), sum(1))
    }
}

thread_local! {
    /// This thread's shard of every [`ShardedCounts`].
    static COUNT_SHARD: usize = next_count_shard();
}
static NEXT_COUNT_SHARD: AtomicUsize = AtomicUsize::new(0);

/// A shard for a new thread (or its packet state).
pub(super) fn next_count_shard() -> usize {
    NEXT_COUNT_SHARD.fetch_add(1, Ordering::Relaxed) % COUNT_SHARDS
}

/// Rays checked against the surface-ray rule and those that saw the field, counted per call or packet
/// and added to the medium's [`ShardedCounts`] once.
#[derive(Default)]
pub(super) struct SurfaceTally {
    pub(super) checked: u64,
    pub(super) saw_field: u64,
}
