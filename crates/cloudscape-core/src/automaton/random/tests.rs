use super::ars::block;
use super::drives::event_thresholds;
#[cfg(target_arch = "x86_64")]
use super::drives::event_thresholds_avx512;
use super::*;
use crate::fields::noise::mix64;
use crate::world::Event;

fn random_q(s: &mut u64) -> [u32; 64] {
    let mut q = [0u32; 64];
    for v in q.iter_mut() {
        *s = mix64(*s);
        *v = match *s % 6 {
            0 => 0,
            1 => 65536,
            2 => (*s >> 20) as u32 % 300,
            _ => (*s >> 20) as u32 % 65537,
        };
    }
    q
}

#[test]
fn ars5_is_aes_rounds_over_the_counter() {
    // An independent AES round (FIPS-197 steps written out here) against the crate's.
    fn xtime(b: u8) -> u8 {
        (b << 1) ^ if b & 0x80 != 0 { 0x1b } else { 0 }
    }
    fn sbox(x: u8) -> u8 {
        // Multiplicative inverse in GF(2^8) (x^254), then the affine map.
        let mul = |mut a: u8, mut b: u8| {
            let mut p = 0u8;
            while b != 0 {
                if b & 1 != 0 {
                    p ^= a;
                }
                a = xtime(a);
                b >>= 1;
            }
            p
        };
        let mut inv = 1u8;
        for _ in 0..254 {
            inv = mul(inv, x);
        }
        let inv = if x == 0 { 0 } else { inv };
        inv ^ inv.rotate_left(1) ^ inv.rotate_left(2) ^ inv.rotate_left(3) ^ inv.rotate_left(4) ^ 0x63
    }
    fn round(s: [u8; 16], k: [u8; 16]) -> [u8; 16] {
        // State byte (row r, column c) is s[r + 4c].
        let sub: Vec<u8> = s.iter().map(|&b| sbox(b)).collect();
        let mut sh = [0u8; 16];
        for c in 0..4 {
            for r in 0..4 {
                sh[r + 4 * c] = sub[r + 4 * ((c + r) % 4)];
            }
        }
        let mut out = [0u8; 16];
        for c in 0..4 {
            let a = &sh[4 * c..4 * c + 4];
            for r in 0..4 {
                let (a0, a1, a2, a3) = (a[r], a[(r + 1) % 4], a[(r + 2) % 4], a[(r + 3) % 4]);
                out[r + 4 * c] = xtime(a0) ^ (xtime(a1) ^ a1) ^ a2 ^ a3 ^ k[r + 4 * c];
            }
        }
        out
    }
    assert_eq!(sbox(0x00), 0x63);
    assert_eq!(sbox(0x53), 0xed);
    let bytes = |v: [u64; 2]| -> [u8; 16] { block(v).into() };
    let mut s = 3u64;
    for _ in 0..50 {
        s = mix64(s);
        let keys = StepKeys::new(s, (s % 7) as u32, (s >> 8) as i64);
        let ctr = [mix64(s ^ 1), mix64(s ^ 2)];
        let mut st = bytes([ctr[0] ^ keys.k[0][0], ctr[1] ^ keys.k[0][1]]);
        for k in &keys.k[1..] {
            st = round(st, bytes(*k));
        }
        assert_eq!(ars5(&keys, ctr), st);
    }
}

#[test]
fn word_draws_equal_lane_draws_on_every_backend() {
    let mut s = 12345u64;
    for _ in 0..300 {
        s = mix64(s);
        let keys = StepKeys::new(s, (s % 11) as u32, (s >> 3) as i64 - (1 << 40));
        let y = (mix64(s ^ 5) >> 20) as i64 - (1 << 43);
        let wx = (mix64(s ^ 6) >> 4) as i64;
        let d = WordDrive::new([&random_q(&mut s), &random_q(&mut s), &random_q(&mut s)]);
        for (e, draw_e) in Event::ALL.into_iter().enumerate() {
            let want: u64 = (0..64u32)
                .filter(|&b| d.always[e] >> b & 1 == 0 && fires(&keys, y, wx, draw_e, b, d.q(e, b)))
                .map(|b| 1u64 << b)
                .sum();
            assert_eq!(below_portable(&keys, y, wx, e, &d.t[e], d.shift[e]), want);
            #[cfg(target_arch = "x86_64")]
            if DrawBackend::Avx512.runs_here() {
                // SAFETY: the CPU has the features (just checked).
                let got = unsafe {
                    avx512::below(
                        &avx512::keys(&keys),
                        avx512::word(avx512::row(y), wx),
                        e,
                        &d.t[e],
                        d.shift[e],
                    )
                };
                assert_eq!(got, want);
            }
        }
    }
}

/// One form of `event_thresholds` over a fixed q.
type Form<'a> = &'a dyn Fn(&mut [u8; 64]) -> (u8, u64, u64);

#[test]
fn event_thresholds_equal_their_scalar_form() {
    let mut s = 77u64;
    for _ in 0..3000 {
        let mut q = random_q(&mut s);
        // Words whose largest threshold sits at every bit length.
        let top = 1 + (mix64(s) % 17) as u32;
        for v in q.iter_mut() {
            if *v < 65536 {
                *v %= 1 << top.min(16);
            }
        }
        // Thresholds above 65536 (never made by `quantize`, but they must read
        // as "always", which a signed compare would get wrong at 2^31 and up).
        if mix64(s).is_multiple_of(4) {
            let b = (mix64(s ^ 1) % 64) as usize;
            q[b] = [65537, 1 << 31, u32::MAX][(mix64(s ^ 2) % 3) as usize];
        }
        // Every form writes into a buffer of garbage (so each must write all 64
        // bytes) and must give the scalar form's mantissas and masks.
        let mut want_m = [0x55; 64];
        let want = event_thresholds_scalar(&q, &mut want_m);
        // The live lanes are the non-zero mantissas.
        let non_zero = (0..64).fold(0u64, |l, b| l | (u64::from(want_m[b] != 0) << b));
        assert_eq!(want.2, non_zero, "{q:?}");
        let check = |name: &str, f: Form| {
            let mut m = [0xaa; 64];
            assert_eq!((f(&mut m), m), (want, want_m), "{name} {q:?}");
        };
        // The baseline form: AVX2 on an x86-64-v3 build.
        check("baseline", &|m| event_thresholds(&q, m));
        #[cfg(target_arch = "x86_64")]
        if crate::fields::noise::NoiseBackend::Avx512.runs_here() {
            // SAFETY: the CPU has AVX-512 F (just checked).
            check("AVX-512", &|m| unsafe { event_thresholds_avx512(&q, m) });
        }
    }
}

#[test]
fn thresholds_keep_eight_bits_relative_to_the_word_maximum() {
    let mut s = 5u64;
    for _ in 0..3000 {
        let q = random_q(&mut s);
        let d = WordDrive::new([&q, &q, &q]);
        let max = q.iter().filter(|&&v| v < 65536).fold(0, |a, &v| a.max(v));
        for b in 0..64u32 {
            let (want, got) = (q[b as usize], d.q(0, b));
            if want >= 65536 || max < 256 {
                assert_eq!(got, want, "exact below 1/256 and at 1");
            } else {
                // Half a unit of the word's scale, the scale being at most max / 128.
                let unit = 1u32 << (8 - d.shift[0]);
                assert!(unit <= max.div_ceil(128).next_power_of_two(), "unit {unit} max {max}");
                assert!(
                    got.abs_diff(want) <= unit / 2 || (got == 255 * unit && want > got),
                    "q {want} -> {got}"
                );
            }
        }
    }
}

#[test]
fn a_levels_words_keep_their_own_thresholds() {
    // Many words, some with lanes that always fire (kept on the side) and some
    // without: every word reads back as it does on its own, and its always
    // lanes as 65536, whichever words before it had some.
    let mut s = 9u64;
    let mut drives = StochasticDrives::default();
    let mut words = Vec::new();
    for i in 0..500 {
        let mut q = [random_q(&mut s), random_q(&mut s), random_q(&mut s)];
        if i % 3 != 0 {
            for v in q.iter_mut().flatten() {
                *v = (*v).min(65535);
            }
        }
        drives.push(q.each_ref());
        words.push(q);
    }
    assert_eq!(drives.len(), words.len());
    for (i, q) in words.iter().enumerate() {
        let d = drives.word(i);
        assert_eq!(d, WordDrive::new(q.each_ref()), "word {i}");
        for (e, q) in q.iter().enumerate() {
            for b in 0..64u32 {
                if q[b as usize] >= 65536 {
                    assert_eq!(d.q(e, b), 65536, "word {i} event {e} lane {b}");
                }
            }
        }
    }
    // Cut at word 250 (its predecessor, 249, has always lanes): the side table
    // keeps the masks of the kept words only, and words pushed after the cut
    // still find theirs.
    drives.truncate(250);
    words.truncate(250);
    let with_always = words.iter().filter(|q| q.iter().flatten().any(|&v| v >= 65536)).count();
    assert_eq!(
        drives.always.len(),
        1 + with_always,
        "the shared entry and the kept words' masks"
    );
    for _ in 0..10 {
        let q = [random_q(&mut s), random_q(&mut s), random_q(&mut s)];
        drives.push(q.each_ref());
        words.push(q);
    }
    assert_eq!(drives.len(), 260);
    for (i, q) in words.iter().enumerate() {
        assert_eq!(drives.word(i), WordDrive::new(q.each_ref()), "word {i} after the cut");
    }
}

/// Runs 640k draws through `fires` for threshold q and checks the rate within
/// 5 standard deviations.
fn check_rate(q: u32) {
    let n = 10_000i64;
    let keys = StepKeys::new(7, 3, 5);
    let mut count = 0u64;
    for w in 0..n {
        count += (0..64)
            .filter(|&b| fires(&keys, 11, w, Event::Activation, b, q))
            .count() as u64;
    }
    let trials = (n * 64) as f64;
    let qp = q as f64 / 65536.0;
    let sd = (trials * qp * (1.0 - qp)).sqrt().max(1.0);
    assert!(
        (count as f64 - trials * qp).abs() < 5.0 * sd,
        "q={q} got {count} want {}",
        trials * qp
    );
}

#[test]
fn rate_matches_probability() {
    for q in [6554, 66, 200, 1, 256, 32768, 65535] {
        check_rate(q);
    }
}

#[test]
fn draws_are_uniform_in_every_lane() {
    // 2^16 draws per lane position, histogram of the high byte: chi-square with
    // 255 degrees of freedom stays below its 1e-6 tail (about 386).
    let keys = StepKeys::new(11, 2, 9);
    for bit in [0u32, 1, 7, 8, 33, 63] {
        let mut hist = [0u32; 256];
        for w in 0..65536i64 {
            hist[(draw(&keys, w >> 8, w & 255, Event::Humidity, bit) >> 8) as usize] += 1;
        }
        let exp = 256.0;
        let chi2: f64 = hist.iter().map(|&c| (c as f64 - exp).powi(2) / exp).sum();
        assert!(chi2 < 386.0, "lane {bit}: chi2 {chi2}");
    }
}

#[test]
fn lanes_words_rows_steps_and_events_are_uncorrelated() {
    // At p = 1/2 a lane and its neighbours in lane, word, row, step and event
    // must agree about half the time; a shared or shifted stream would not.
    let q = 32768;
    let n = 4_000i64;
    let k0 = StepKeys::new(3, 0, 100);
    let k1 = StepKeys::new(3, 0, 101);
    let kl = StepKeys::new(3, 1, 100);
    let mut same = [0u64; 6];
    let mut pairs = 0u64;
    for w in 0..n {
        for b in 0..64u32 {
            let f = fires(&k0, 5, w, Event::Humidity, b, q);
            let others = [
                fires(&k0, 5, w, Event::Humidity, (b + 1) % 64, q),
                fires(&k0, 5, w + 1, Event::Humidity, b, q),
                fires(&k0, 6, w, Event::Humidity, b, q),
                fires(&k1, 5, w, Event::Humidity, b, q),
                fires(&k0, 5, w, Event::Extinction, b, q),
                fires(&kl, 5, w, Event::Humidity, b, q),
            ];
            for (s, o) in same.iter_mut().zip(others) {
                *s += u64::from(f == o);
            }
            pairs += 1;
        }
    }
    let sd = (pairs as f64 * 0.25).sqrt();
    for (name, c) in ["lane", "word", "row", "step", "event", "level"].iter().zip(same) {
        assert!(
            (c as f64 - pairs as f64 / 2.0).abs() < 5.0 * sd,
            "{name}: {c} of {pairs}"
        );
    }
}

#[test]
fn counters_are_distinct() {
    let mut seen = std::collections::HashSet::new();
    for y in [-(1i64 << 57), -1, 0, 1, 1 << 40] {
        for wx in [i64::MIN, -1, 0, 1, i64::MAX] {
            for e in 0..3 {
                for g in 0..8 {
                    assert!(seen.insert(counter(y, wx, e, g)));
                }
            }
        }
    }
}
