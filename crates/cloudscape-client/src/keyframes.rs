//! The keyframes a client holds, decoded: what it draws, and what the next keyframe's
//! delta form (`billboards.delta.bin`) is decoded against.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use cloudscape_core::products::billboards::BinBillboards;

/// Most tile variants whose keyframes are held; past it the least recently stored go.
const MAX_VARIANTS: usize = 1024;
/// Keyframes held per variant: the one drawn, the next (prefetched), one spare.
const PER_VARIANT: usize = 3;

/// Decoded keyframes by tile variant (world, layer, tile, quality, sun) and start time.
#[derive(Default)]
pub(crate) struct HeldKeyframes {
    by_variant: HashMap<String, Vec<(u64, Arc<BinBillboards>)>>,
    order: VecDeque<String>,
}

impl HeldKeyframes {
    /// The keyframe of `variant` that starts at `t0`.
    pub(crate) fn get(&self, variant: &str, t0: f64) -> Option<Arc<BinBillboards>> {
        let held = self.by_variant.get(variant)?;
        held.iter()
            .find(|(t, _)| *t == t0.to_bits())
            .map(|(_, k)| Arc::clone(k))
    }

    /// The keyframe of `variant` that ends at `t0` (its successor starts there), if held.
    pub(crate) fn ending_at(&self, variant: &str, t0: f64) -> Option<Arc<BinBillboards>> {
        let held = self.by_variant.get(variant)?;
        held.iter()
            .map(|(_, k)| k)
            .find(|k| {
                k.keyframe
                    .is_some_and(|[_, t1]| (t1 - t0).abs() <= 1e-9 * t0.abs().max(1.0))
            })
            .map(Arc::clone)
    }

    /// Holds `keyframe` of `variant` starting at `t0`, forgetting the oldest beyond the
    /// bounds.
    pub(crate) fn insert(&mut self, variant: &str, t0: f64, keyframe: Arc<BinBillboards>) {
        let held = match self.by_variant.get_mut(variant) {
            Some(h) => h,
            None => {
                if self.order.len() >= MAX_VARIANTS
                    && let Some(old) = self.order.pop_front()
                {
                    self.by_variant.remove(&old);
                }
                self.order.push_back(variant.to_string());
                self.by_variant.entry(variant.to_string()).or_default()
            }
        };
        held.retain(|(t, _)| *t != t0.to_bits());
        held.push((t0.to_bits(), keyframe));
        held.sort_by(|a, b| f64::from_bits(a.0).total_cmp(&f64::from_bits(b.0)));
        while held.len() > PER_VARIANT {
            held.remove(0);
        }
    }
}
