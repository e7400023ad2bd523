//! How much the groups share: per level, the distinct tile keyframes the players asked
//! for during the measured time and how many groups asked for each. A keyframe is one
//! tile (layer, level, x, y) at one keyframe time, whatever the product: the server
//! computes a tile's keyframe once for all its products.

use std::collections::{BTreeMap, HashMap};

use serde::Serialize;

/// One tile keyframe: the unit of work the server computes once and every group that
/// asks for it shares.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct KeyframeKey {
    /// Index of the layer in the world's order.
    pub layer: u16,
    pub z: u32,
    pub x: i64,
    pub y: i64,
    /// The keyframe's `t0`, as `f64::to_bits` (keyframe times are exact multiples of a span).
    pub t0_bits: u64,
}

/// Who asked for one keyframe.
#[derive(Clone, Debug, Default)]
struct Asks {
    requests: u64,
    /// Distinct groups, sorted.
    groups: Vec<u32>,
}

/// The tile requests of a run, by keyframe.
#[derive(Clone, Debug, Default)]
pub struct SharingLog {
    keyframes: HashMap<KeyframeKey, Asks>,
}

/// How much the groups shared at one level.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct LevelSharing {
    pub level: u32,
    /// Distinct keyframes asked for (all layers of the level).
    pub keyframes: u64,
    /// Tile requests for them (every product, prefetches included).
    pub requests: u64,
    /// `requests / keyframes`.
    pub requests_per_keyframe: f64,
    /// Mean number of distinct groups that asked for a keyframe.
    pub groups_per_keyframe: f64,
    /// Share of the keyframes asked for by two groups or more.
    pub shared_by_2_groups: f64,
}

impl SharingLog {
    /// Notes one tile request of group `group`.
    pub fn record(&mut self, key: KeyframeKey, group: u32) {
        let asks = self.keyframes.entry(key).or_default();
        asks.requests += 1;
        if let Err(i) = asks.groups.binary_search(&group) {
            asks.groups.insert(i, group);
        }
    }

    /// The figures per level, finest first.
    pub fn by_level(&self) -> Vec<LevelSharing> {
        // level → (keyframes, requests, sum of groups, keyframes with ≥ 2 groups)
        let mut levels: BTreeMap<u32, (u64, u64, u64, u64)> = BTreeMap::new();
        for (key, asks) in &self.keyframes {
            let l = levels.entry(key.z).or_default();
            l.0 += 1;
            l.1 += asks.requests;
            l.2 += asks.groups.len() as u64;
            l.3 += u64::from(asks.groups.len() >= 2);
        }
        levels
            .into_iter()
            .map(|(level, (keyframes, requests, groups, shared))| LevelSharing {
                level,
                keyframes,
                requests,
                requests_per_keyframe: requests as f64 / keyframes as f64,
                groups_per_keyframe: groups as f64 / keyframes as f64,
                shared_by_2_groups: shared as f64 / keyframes as f64,
            })
            .collect()
    }
}

/// All levels as one: distinct keyframes, requests per keyframe and the share asked by
/// two groups or more (`None` without tile requests).
pub fn overall(levels: &[LevelSharing]) -> Option<LevelSharing> {
    let keyframes: u64 = levels.iter().map(|l| l.keyframes).sum();
    let requests: u64 = levels.iter().map(|l| l.requests).sum();
    let weighted = |f: fn(&LevelSharing) -> f64| levels.iter().map(|l| f(l) * l.keyframes as f64).sum::<f64>();
    (keyframes > 0).then(|| LevelSharing {
        level: u32::MAX,
        keyframes,
        requests,
        requests_per_keyframe: requests as f64 / keyframes as f64,
        groups_per_keyframe: weighted(|l| l.groups_per_keyframe) / keyframes as f64,
        shared_by_2_groups: weighted(|l| l.shared_by_2_groups) / keyframes as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(z: u32, x: i64, t0: f64) -> KeyframeKey {
        KeyframeKey {
            layer: 0,
            z,
            x,
            y: 0,
            t0_bits: t0.to_bits(),
        }
    }

    #[test]
    fn sharing_is_counted_per_level_by_hand() {
        let mut log = SharingLog::default();
        // Level 0: keyframe A asked by groups 0 (twice: both products) and 1;
        // keyframe B by group 2 only; A's next keyframe by group 0.
        for (k, g) in [
            (key(0, 5, 20.0), 0),
            (key(0, 5, 20.0), 0),
            (key(0, 5, 20.0), 1),
            (key(0, 6, 20.0), 2),
            (key(0, 5, 40.0), 0),
            // Level 3: one keyframe, asked by groups 0, 1 and 2, four requests.
            (key(3, 0, 160.0), 2),
            (key(3, 0, 160.0), 0),
            (key(3, 0, 160.0), 1),
            (key(3, 0, 160.0), 1),
        ] {
            log.record(k, g);
        }
        // Another layer is another keyframe at the same level.
        log.record(
            KeyframeKey {
                layer: 1,
                ..key(3, 0, 160.0)
            },
            0,
        );
        let levels = log.by_level();
        assert_eq!(
            levels,
            vec![
                LevelSharing {
                    level: 0,
                    keyframes: 3,
                    requests: 5,
                    requests_per_keyframe: 5.0 / 3.0,
                    groups_per_keyframe: 4.0 / 3.0,
                    shared_by_2_groups: 1.0 / 3.0,
                },
                LevelSharing {
                    level: 3,
                    keyframes: 2,
                    requests: 5,
                    requests_per_keyframe: 2.5,
                    groups_per_keyframe: 2.0,
                    shared_by_2_groups: 0.5,
                },
            ]
        );
        let all = overall(&levels).unwrap();
        assert_eq!((all.keyframes, all.requests), (5, 10));
        assert!((all.requests_per_keyframe - 2.0).abs() < 1e-12);
        assert!((all.groups_per_keyframe - 8.0 / 5.0).abs() < 1e-12);
        assert!((all.shared_by_2_groups - 2.0 / 5.0).abs() < 1e-12);
        assert!(overall(&[]).is_none());
    }
}
