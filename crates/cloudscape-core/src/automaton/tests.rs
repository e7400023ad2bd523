//! The packed kernel against the naive reference, bit for bit, on random grids,
//! random drives and random frame shifts (edges included: cells outside a grid
//! read as empty in both).

use proptest::prelude::*;

use super::kernel::{Drives, Level, Rect, Rules, StepContext, step_level, step_level_on};
use super::naive::{NaiveDrives, NaiveLevel, step};
use super::random::{DrawBackend, StochasticDrives};
use crate::cpu::Backend;
use crate::fields::noise::mix64;

/// Dobashi drives from per-cell thresholds q (0..=65536) of (hum, act, ext), 64 cells per word.
fn stochastic(q: [&[u32]; 3]) -> Drives {
    let lanes = |e: usize, i: usize| -> &[u32; 64] { q[e][64 * i..64 * (i + 1)].try_into().expect("64 lanes") };
    let mut d = StochasticDrives::with_capacity(q[0].len() / 64);
    for i in 0..q[0].len() / 64 {
        d.push([lanes(0, i), lanes(1, i), lanes(2, i)]);
    }
    Drives::Stochastic(d)
}

/// A random scene: per level a grid (origin, words per row, rows), cells and
/// thresholds. Levels differ in size, so a z neighbour's row is often narrower or
/// wider than the level reading it.
#[derive(Debug, Clone)]
struct Scene {
    rules: Rules,
    grids: Vec<(i64, i64, usize, usize)>,
    offsets: Vec<Vec<(i64, i64)>>,
    seed: u64,
    density: u8,
}

fn scene() -> impl Strategy<Value = Scene> {
    (
        // Dobashi more often: it is the mode with per-backend kernels.
        prop_oneof![3 => Just(Rules::Dobashi), 1 => Just(Rules::Rosa)],
        1usize..5,
        any::<u64>(),
        0u8..4,
    )
        .prop_flat_map(|(rules, depth, seed, density)| {
            let grid = (-3i64..3, -20i64..20, prop_oneof![1usize..4, 4usize..24], 1usize..12)
                .prop_map(|(wx, y, wpr, rows)| (wx * 64, y, wpr, rows));
            let offs = proptest::collection::vec((-70i64..70, -6i64..6), depth);
            (
                Just(rules),
                proptest::collection::vec(grid, depth),
                proptest::collection::vec(offs, 3),
                Just(seed),
                Just(density),
            )
        })
        .prop_map(|(rules, grids, offsets, seed, density)| Scene {
            rules,
            grids,
            offsets,
            seed,
            density,
        })
}

fn random_bits(s: &mut u64, density: u8) -> u64 {
    *s = mix64(*s);
    let a = *s;
    *s = mix64(*s);
    match density {
        0 => a & *s,
        1 => a,
        2 => a | *s,
        _ => 0,
    }
}

fn threshold(s: &mut u64) -> u32 {
    *s = mix64(*s);
    match *s % 6 {
        0 | 1 => 0,
        2 => 65536,
        3 => (*s >> 40) as u32 % 256,
        _ => (*s >> 20) as u32 % 65537,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]
    #[test]
    fn packed_equals_naive(sc in scene()) {
        let mut s = sc.seed;
        let depth = sc.grids.len();
        let mut packed: Vec<Level> = Vec::new();
        let mut naive: Vec<NaiveLevel> = Vec::new();
        let mut pdrives = Vec::new();
        let mut ndrives = Vec::new();
        for &(x0, y0, wpr, rows) in &sc.grids {
            let mut lv = Level::covering(Rect { x0, x1: x0 + 64 * wpr as i64, y0, y1: y0 + rows as i64 });
            for i in 0..lv.hum.len() {
                lv.hum[i] = random_bits(&mut s, sc.density);
                lv.act[i] = random_bits(&mut s, sc.density);
                lv.cld[i] = random_bits(&mut s, sc.density);
            }
            let w = wpr * 64;
            let unpack = |v: &[u64]| -> Vec<u8> { (0..w * rows).map(|c| ((v[(c / w) * wpr + (c % w) / 64] >> (c % 64)) & 1) as u8).collect() };
            naive.push(NaiveLevel { x0, y0, w, h: rows, hum: unpack(&lv.hum), act: unpack(&lv.act), cld: unpack(&lv.cld) });
            match sc.rules {
                Rules::Dobashi => {
                    // Half the levels have no lane that always fires (the AVX-512
                    // kernel then reads no `always` masks); in the others a third of
                    // the words have none (they share the side table's empty entry).
                    s = mix64(s);
                    let level_cap = s % 2 == 0;
                    let word_cap: Vec<bool> = (0..wpr * rows).map(|_| { s = mix64(s); level_cap || s % 3 == 0 }).collect();
                    let q: Vec<Vec<u32>> = (0..3)
                        .map(|_| (0..w * rows).map(|c| threshold(&mut s).min(if word_cap[c / 64] { 65535 } else { 65536 })).collect())
                        .collect();
                    let d = stochastic([&q[0], &q[1], &q[2]]);
                    // The naive kernel draws against the thresholds the packed drives hold.
                    let Drives::Stochastic(words) = &d else { unreachable!() };
                    let held = |e: usize| -> Vec<u32> { (0..w * rows).map(|c| words.word(c / 64).q(e, (c % 64) as u32)).collect() };
                    ndrives.push(NaiveDrives::Stochastic { hum: held(0), act: held(1), ext: held(2) });
                    pdrives.push(d);
                }
                Rules::Rosa => {
                    let m: Vec<Vec<u64>> = (0..3).map(|_| (0..lv.hum.len()).map(|_| random_bits(&mut s, 1)).collect()).collect();
                    ndrives.push(NaiveDrives::Threshold { hum: unpack(&m[0]), act: unpack(&m[1]), keep: unpack(&m[2]) });
                    pdrives.push(Drives::Threshold { hum: m[0].clone(), act: m[1].clone(), keep: m[2].clone() });
                }
            }
            packed.push(lv);
        }
        let stream = mix64(sc.seed ^ 1);
        for (i, offsets) in sc.offsets.iter().enumerate() {
            let n = -5 + i as i64 * 1_000_003;
            let ctx = StepContext { rules: sc.rules, stream, n, offsets };
            // Every backend this CPU has (the default one first) makes the same step.
            let mut results: Vec<Vec<Level>> = Vec::new();
            for backend in std::iter::once(DrawBackend::detect()).chain(DrawBackend::available().iter().copied()) {
                let mut next = packed.clone();
                for k in 0..depth {
                    let lv = &packed[k];
                    let all = Rect { x0: lv.x0, x1: lv.x0 + 64 * lv.wpr as i64, y0: lv.y0, y1: lv.y0 + lv.rows as i64 };
                    if backend == DrawBackend::detect() {
                        step_level(&packed, k, &pdrives[k], &ctx, all, &mut next[k]);
                    } else {
                        step_level_on(backend, &packed, k, &pdrives[k], &ctx, all, &mut next[k]);
                    }
                }
                results.push(next);
            }
            for r in &results[1..] {
                prop_assert_eq!(r, &results[0]);
            }
            // A window that covers part of each grid (as a run's shrinking cone does),
            // or reaches past it: every backend computes exactly the words covering it,
            // the same as the full step, and leaves every other word as it was.
            const UNTOUCHED: u64 = 0xa5a5_5a5a_0ff0_f00f;
            for &backend in DrawBackend::available() {
                let mut t = s ^ i as u64;
                for k in 0..depth {
                    let lv = &packed[k];
                    let mut pick = |lo: i64, hi: i64| { t = mix64(t); lo + (t % (hi - lo + 1) as u64) as i64 };
                    let (x1, y1) = (lv.x0 + 64 * lv.wpr as i64, lv.y0 + lv.rows as i64);
                    let (wx0, wy0) = (pick(lv.x0 - 70, x1), pick(lv.y0 - 3, y1));
                    let window = Rect { x0: wx0, x1: pick(wx0, x1 + 70), y0: wy0, y1: pick(wy0, y1 + 3) };
                    let mut out = lv.clone();
                    for v in [&mut out.hum, &mut out.act, &mut out.cld] {
                        v.fill(UNTOUCHED);
                    }
                    step_level_on(backend, &packed, k, &pdrives[k], &ctx, window, &mut out);
                    let full = &results[0][k];
                    for r in 0..lv.rows {
                        for w in 0..lv.wpr {
                            let (y, x) = (lv.y0 + r as i64, lv.x0 + 64 * w as i64);
                            let covered = !window.is_empty() && y >= window.y0 && y < window.y1 && x + 64 > window.x0 && x < window.x1;
                            let j = r * lv.wpr + w;
                            for (got, want) in [(&out.hum, &full.hum), (&out.act, &full.act), (&out.cld, &full.cld)] {
                                let want = if covered { want[j] } else { UNTOUCHED };
                                prop_assert_eq!(got[j], want, "{:?} level {} window {:?} row {} word {}", backend, k, window, r, w);
                            }
                        }
                    }
                }
            }
            packed = results.swap_remove(0);
            naive = step(&naive, &ndrives, sc.rules, stream, n, offsets);
            for k in 0..depth {
                let (p, q) = (&packed[k], &naive[k]);
                for r in 0..q.h {
                    for c in 0..q.w {
                        let bit = |v: &[u64]| ((v[r * p.wpr + c / 64] >> (c % 64)) & 1) as u8;
                        let i = r * q.w + c;
                        prop_assert_eq!(bit(&p.hum), q.hum[i], "hum level {} cell {},{} step {}", k, c, r, i);
                        prop_assert_eq!(bit(&p.act), q.act[i], "act level {} cell {},{} step {}", k, c, r, i);
                        prop_assert_eq!(bit(&p.cld), q.cld[i], "cld level {} cell {},{} step {}", k, c, r, i);
                    }
                }
            }
        }
    }
}
