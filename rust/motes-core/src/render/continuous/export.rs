//! A field as flat arrays for a walk written outside the core (issue 46's Dr.Jit kernel,
//! `mitsuba_plugin/motes/drjit_field.py`): its cells' frame and σ_t, and per cell its entries, one per
//! optics bin, each with its share of the cell's extinction. An interaction in the field picks a member
//! ∝ its share (`ContinuousField::pick`) and scatters with its bin's albedo and phase function (module
//! docs, "Why this is the same medium"): the cell's bins and their shares are all a walk needs.

use super::{ContinuousField, Members, CLASS_FLAG};
use rayon::prelude::*;

/// [`ContinuousField::flat`]: the cells (corner `lo`, edges `cell`, counts `dims`, x fastest), σ_t of
/// each (grey, per scene unit) and its entries `start[c]..start[c + 1]` of `bin` and `share` (of the
/// cell's extinction; one entry per bin, in increasing bin order; none in a cell of σ_t = 0).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlatField {
    pub lo: [f64; 3],
    pub cell: [f64; 3],
    pub dims: [u32; 3],
    pub sigma: Vec<f32>,
    pub start: Vec<u32>,
    pub bin: Vec<u32>,
    pub share: Vec<f32>,
}

impl ContinuousField {
    /// Each member of cell `c` with its share of the cell's extinction in units of 1/65535 (the
    /// difference of its running share and the one before it: what [`Self::pick`] picks it with), as
    /// [`Self::member_extinction`] reads them (units, not the share, so that it multiplies before it
    /// divides, as it always has: its sums stay bit for bit). Nothing for a cell of σ_t = 0.
    pub(super) fn cell_shares(&self, c: usize, f: &mut dyn FnMut(u32, f64)) {
        if self.sigma[c] <= 0.0 {
            return;
        }
        let mut run = |cdf: &mut dyn Iterator<Item = (u32, u32)>| {
            let mut below = 0u32;
            for (member, up) in cdf {
                f(member, (up - below.min(up)) as f64);
                below = up;
            }
        };
        if let Some((first, packed)) = &self.picks {
            let entries = &packed[first[c] as usize..first[c + 1] as usize];
            return run(&mut entries
                .iter()
                .map(|&x| (CLASS_FLAG | (x & 0xFFFF), x >> 16)));
        }
        let (a, b) = self.range(c);
        match &self.members {
            Members::Classes(v) => run(&mut v[a..b]
                .iter()
                .map(|&x| (CLASS_FLAG | (x & 0xFFFF), x >> 16))),
            _ => run(&mut (a..b).map(|j| (self.members.get(j), self.cdf[j] as u32))),
        }
    }

    /// The field as flat arrays ([`FlatField`]), each member mapped to its optics bin by `bin_of` (a
    /// particle's index or a class code with [`CLASS_FLAG`], as [`Self::pick`] returns them); the
    /// shares of a cell's members of one bin summed.
    pub fn flat(&self, bin_of: impl Fn(u32) -> u32 + Sync) -> FlatField {
        let per_cell: Vec<Vec<(u32, f64)>> = (0..self.sigma.len())
            .into_par_iter()
            .map(|c| {
                let mut entries: Vec<(u32, f64)> = Vec::new();
                self.cell_shares(c, &mut |member, units| {
                    let share = units / u16::MAX as f64;
                    let b = bin_of(member);
                    match entries.iter_mut().find(|e| e.0 == b) {
                        Some(e) => e.1 += share,
                        None => entries.push((b, share)),
                    }
                });
                entries.retain(|e| e.1 > 0.0);
                entries.sort_unstable_by_key(|e| e.0);
                entries
            })
            .collect();
        let mut start = Vec::with_capacity(per_cell.len() + 1);
        start.push(0u32);
        let total: usize = per_cell.iter().map(Vec::len).sum();
        let (mut bin, mut share) = (Vec::with_capacity(total), Vec::with_capacity(total));
        for entries in &per_cell {
            for &(b, s) in entries {
                bin.push(b);
                share.push(s as f32);
            }
            start.push(bin.len() as u32);
        }
        FlatField {
            lo: self.frame.bounds.lo,
            cell: self.frame.cell,
            dims: self.frame.dims.map(|d| d as u32),
            sigma: self.sigma.clone(),
            start,
            bin,
            share,
        }
    }
}
