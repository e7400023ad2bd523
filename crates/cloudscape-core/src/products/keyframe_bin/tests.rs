use super::*;
use crate::cancel::Cancel;
use crate::products::billboards::{decode_bin, decode_bin_after};
use crate::render::{Quality, ShadingParams, Sun, TileId, shade_tile};
use crate::world::{Config, Keyframe};

fn shaded(tile: TileId, t: f64, quality: Quality, sun: Sun) -> ShadedTile {
    let config = Config::embedded();
    let world = config.world("default").unwrap();
    shade_tile(
        &world,
        0,
        tile,
        Keyframe::containing(t, &world.layers[0], tile.z),
        quality,
        sun,
        &ShadingParams::default(),
        &config.limits,
        &Cancel::never(),
    )
    .unwrap()
}

/// The length of plane `p` from a keyframe's plane table.
fn plane_len(bytes: &[u8], p: usize) -> usize {
    let levels = u16::from_le_bytes([bytes[190], bytes[191]]) as usize;
    let at = FIXED_BYTES + LEVEL_BYTES * levels + 4 * p;
    u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize
}

fn fast(tile: TileId, t: f64) -> ShadedTile {
    shaded(tile, t, Quality::Fast, Sun::new(120.0, 30.0).unwrap())
}

/// The largest error of a quantised colour: half a step of `(c / 2)^(1/2.2)` on
/// `levels` steps, taken back through the power at `c`.
/// Half a colour step around `c`, in linear colour: since ALGORITHM_VERSION 13 the steps
/// are even in the displayed value `(1 − e^{−3c})^(1/2.2)` (docs/formats.md "Codes"),
/// written out here rather than taken from the code under test.
fn colour_tolerance(c: f32, bits: u8) -> f32 {
    let levels = ((1u32 << bits) - 1) as f64;
    let c = (c as f64).clamp(0.0, 2.0);
    let g = (1.0 - (-3.0 * c).exp()).powf(1.0 / 2.2);
    let linear = |q: f64| (-(1.0 - q.clamp(0.0, 1.0).powf(2.2)).ln() / 3.0).min(2.0);
    let up = linear(g + 0.5 / levels);
    let down = linear(g - 0.5 / levels);
    ((up - c).abs().max((c - down).abs()) * 1.0001 + 1e-6) as f32
}

/// The sun term of a billboard colour of `tile` at sun optical depth `tau_sun`,
/// written out from its lighting (`albedo · sun_rgb / 4 · Σ bⁱ e^{−aⁱ τ}`, the
/// shader's form) rather than taken from the code under test.
fn sun_term(tile: &ShadedTile, tau_sun: f32) -> [f64; 3] {
    let l = &tile.lighting;
    let o = l.billboard.octaves;
    let (mut w, mut att, mut sum) = (1.0, 1.0, 0.0);
    for _ in 0..o.count {
        sum += w * (-att * tau_sun.max(0.0) as f64).exp();
        w *= o.contribution;
        att *= o.attenuation;
    }
    l.sun_rgb.map(|c| l.params.albedo * c / 4.0 * sum)
}

#[test]
fn under_a_deck_a_billboard_keeps_one_colour_step() {
    // A client drawing a billboard under another layer takes the sun term out of the
    // colour and evaluates it deeper (Lighting::beneath_layers). Deep under a deck what
    // is left is the ambient, small and dark: it must keep the precision of one
    // colour step on the display, not carry the rounding of the bright whole colour.
    let s = fast(TileId { z: 0, x: 0, y: 0 }, 43210.0);
    let q = Quantisation::DEFAULT;
    let d = decode_bin(&encode(&s, Form::SelfContained, q)).unwrap();
    let shown = |x: f32| crate::render::light::tone_map(x as f64);
    let mut worst: f64 = 0.0;
    let mut lit = 0;
    for (r, b) in d.records.iter().zip(&s.billboards) {
        if !(b.splat_tau > 0.0) {
            continue;
        }
        // Sunlit enough that the sun term dominates the colour.
        lit += usize::from(sun_term(&s, b.tau_sun)[1] > 2.0 * b.colour[1] as f64 / 3.0);
        let exact = s.lighting.beneath_layers(b.colour, b.tau_sun, 6.0, 0.0).0;
        let drawn = s
            .lighting
            .beneath_layers(r.ends[0].colour, r.ends[0].tau_sun, 6.0, 0.0)
            .0;
        for c in 0..3 {
            worst = worst.max((shown(drawn[c]) - shown(exact[c])).abs());
        }
    }
    assert!(lit > 100, "{lit} sunlit billboards");
    // Half a step of 63, plus what e^{−6} leaves of the sun term's rounding.
    assert!(worst <= 0.5 / 63.0 + 0.002, "{:.2}/255 off under a deck", worst * 255.0);
}

#[test]
fn colour_codes_are_even_display_steps_at_the_served_exposure() {
    // The format fixes its exposure; the tone map's must be the same, or the codes
    // stop being even steps of what is displayed (change the format with it).
    assert_eq!(CODE_EXPOSURE, crate::render::light::EXPOSURE);
    let curve = ColourCurve::of(crate::world::ALGORITHM_VERSION);
    assert_eq!(curve, ColourCurve::Display);
    let codes = Codes::new(Quantisation::DEFAULT, curve);
    let shown = |x: f32| crate::render::light::tone_map(x as f64);
    for i in 0..=2000 {
        let c = i as f32 / 1000.0;
        let back = codes.colour_value(codes.colour(c));
        // Half a step of 63 on the display, whatever the colour.
        assert!((shown(back) - shown(c)).abs() <= 0.5 / 63.0 + 1e-6, "{c} → {back}");
    }
    assert_eq!(codes.colour_value(codes.colour(f32::INFINITY)), 2.0);
    assert_eq!(codes.colour_value(codes.colour(f32::NAN)), 0.0);
    // Files of earlier versions keep their curve.
    let old = Codes::new(Quantisation::DEFAULT, ColourCurve::of(12));
    assert_eq!(old.colour_value(63), 2.0);
    assert!((old.colour_value(old.colour(0.5)) - 0.5).abs() < 0.02);
}

#[test]
fn sites_are_the_lattice_points_in_the_tile() {
    let s = fast(TileId { z: 0, x: 0, y: -1 }, 43210.0);
    let g = SiteGeometry::of(&s);
    let lattice = s.lattice.at(s.keyframe.t0);
    let owned = [s.origin[0], s.origin[1], s.origin[0] + s.size, s.origin[1] + s.size];
    let inside = |c: [f64; 3]| c[0] >= owned[0] && c[0] < owned[2] && c[1] >= owned[1] && c[1] < owned[3];
    // Brute force over a margin around the tile: `contains` is the centre's own test.
    let n = (s.size / g.spacing).ceil() as i64 + 4;
    let (i_lo, j_lo) = (
        (owned[0] / g.spacing).floor() as i64 - 3,
        (owned[1] / g.spacing).floor() as i64 - 3,
    );
    let mut sites = 0;
    for (k, l) in g.levels.iter().enumerate() {
        for j in j_lo..j_lo + n + 3 {
            for i in i_lo..i_lo + n + 3 {
                let c = lattice.centre(i, j, k as i64);
                assert_eq!(g.centre(i, j, k), c, "the site's centre is the lattice's");
                assert_eq!(l.contains(k, i, j), inside(c), "site {i},{j},{k}");
                sites += inside(c) as usize;
            }
        }
    }
    let expected = (s.size / g.spacing).powi(2) * g.levels.len() as f64;
    assert!(
        (sites as f64 - expected).abs() < 0.02 * expected,
        "{sites} sites, about {expected}"
    );
    // Every ball the tile starts with is at a site.
    for b in &s.billboards {
        assert!(g.levels[b.index[2] as usize].contains(b.index[2] as usize, b.index[0], b.index[1]));
    }
}

#[test]
fn self_contained_keyframe_round_trips_within_its_steps() {
    let s = fast(TileId { z: 0, x: 0, y: 0 }, 43210.0);
    let q = Quantisation::DEFAULT;
    let bytes = encode(&s, Form::SelfContained, q);
    let d = decode_bin(&bytes).unwrap();
    assert_eq!((d.version, d.z, d.x, d.y), (3, 0, 0, 0));
    assert_eq!(d.keyframe, Some([43200.0, 43220.0]));
    assert_eq!(d.algorithm_version, Some(ALGORITHM_VERSION));
    assert_eq!(d.lighting.unwrap().sun_direction, s.lighting.sun_dir.map(|v| v as f32));
    // The same billboards as the tile, in the same order: every pair of ends.
    assert_eq!(d.records.len(), s.billboards.len());
    let steps = q.tau_sun_steps as f32;
    for (r, (a, b)) in d.records.iter().zip(s.billboards.iter().zip(&s.end)) {
        // Position, radius and velocity are the lattice's, as version 2 wrote them.
        assert_eq!(
            r.offset,
            [
                (a.centre[0] - s.origin[0]) as f32,
                (a.centre[1] - s.origin[1]) as f32,
                a.centre[2] as f32
            ]
        );
        assert_eq!(r.radius, a.radius);
        assert_eq!(r.velocity, s.velocity_at(a.centre[2]).map(|v| v as f32));
        for (end, bb, other) in [(&r.ends[0], a, b), (&r.ends[1], b, a)] {
            // Splats exactly; an end without a ball draws nothing.
            assert_eq!(end.splat_tau, Some(bb.splat_tau), "{:?}", bb.index);
            if bb.splat_tau > 0.0 {
                assert_eq!(end.splat, bb.splat);
            }
            // An end without a ball keeps the other end's light.
            let light = if bb.splat_tau > 0.0 { bb } else { other };
            // The codes carry the ambient (the colour less its sun term) within half a
            // display step; the sun term follows from the dequantised τ_sun.
            let (sun, sun_q) = (sun_term(&s, light.tau_sun), sun_term(&s, end.tau_sun));
            for c in 0..3 {
                let ambient = (light.colour[c] as f64 - sun[c]).max(0.0) as f32;
                let got = (end.colour[c] as f64 - sun_q[c]) as f32;
                let tol = colour_tolerance(ambient, q.colour_bits) + 1e-5;
                if end.colour[c] < 2.0 {
                    assert!(
                        (got - ambient).abs() <= tol,
                        "channel {c}: ambient {got} for {ambient} (±{tol})"
                    );
                }
                let tol = tol + (sun_q[c] - sun[c]).abs() as f32;
                assert!(
                    (end.colour[c] - light.colour[c]).abs() <= tol,
                    "channel {c}: {} for {} (±{tol})",
                    end.colour[c],
                    light.colour[c]
                );
            }
            let t = light.tau_sun.max(TAU_SUN_FLOOR);
            let ratio = (end.tau_sun / t).ln().abs();
            assert!(ratio <= 0.5 / steps + 1e-5, "τ_sun {} for {t}", end.tau_sun);
            // What follows from others does.
            assert_eq!(end.opacity, to_u8(1.0 - (-end.splat_tau.unwrap()).exp()));
            assert_eq!(end.sun_transmittance, to_u8((-end.tau_sun).exp()));
        }
    }
    // A small fraction of version 2's size, before any compression.
    let v2 = crate::products::billboards::encode_bin(&s);
    assert!(bytes.len() * 3 < v2.len(), "{} bytes against {}", bytes.len(), v2.len());
}

#[test]
fn a_delta_on_the_previous_keyframe_decodes_to_the_self_contained_form() {
    let tile = TileId { z: 0, x: 1, y: -1 };
    let q = Quantisation::DEFAULT;
    let mut previous = decode_bin(&encode(&fast(tile, 43190.0), Form::SelfContained, q)).unwrap();
    for t in [43210.0, 43230.0, 43250.0] {
        let s = fast(tile, t);
        let full = encode(&s, Form::SelfContained, q);
        let delta = encode(&s, Form::Delta, q);
        assert_eq!(u16::from_le_bytes([delta[6], delta[7]]), 1, "a delta says so");
        // The delta codes the start of only the sites the wind brought in.
        let start_bytes = |b: &[u8]| (0..6).map(|p| plane_len(b, p)).sum::<usize>();
        assert!(
            start_bytes(&delta) * 10 < start_bytes(&full),
            "delta start {} bytes, full {}",
            start_bytes(&delta),
            start_bytes(&full)
        );
        let whole = decode_bin(&full).unwrap();
        let chained = decode_bin_after(&delta, Some(&previous)).unwrap();
        assert_eq!(chained, whole, "t = {t}");
        // A self-contained keyframe ignores what it is given.
        assert_eq!(decode_bin_after(&full, Some(&previous)).unwrap(), whole);
        previous = chained;
    }
}

#[test]
fn a_delta_refuses_a_missing_or_wrong_previous_keyframe() {
    let tile = TileId { z: 0, x: 0, y: 0 };
    let q = Quantisation::DEFAULT;
    let delta = encode(&fast(tile, 43230.0), Form::Delta, q);
    let e = decode_bin(&delta).unwrap_err();
    assert!(e.contains("needs the previous keyframe"), "{e}");
    // Two spans back, or another tile: refused with what it follows.
    let old = decode_bin(&encode(&fast(tile, 43190.0), Form::SelfContained, q)).unwrap();
    let e = decode_bin_after(&delta, Some(&old)).unwrap_err();
    assert!(e.contains("follows keyframe"), "{e}");
    let other = decode_bin(&encode(
        &fast(TileId { z: 0, x: 1, y: 0 }, 43210.0),
        Form::SelfContained,
        q,
    ))
    .unwrap();
    assert!(decode_bin_after(&delta, Some(&other)).is_err());
    // A version-2 keyframe has no lattice to follow.
    let v2 = decode_bin(&crate::products::billboards::encode_bin(&fast(tile, 43210.0))).unwrap();
    assert!(decode_bin_after(&delta, Some(&v2)).is_err());
}

#[test]
fn the_first_keyframe_and_instants_are_always_self_contained() {
    let tile = TileId { z: 0, x: 0, y: 0 };
    let first = encode(&fast(tile, 5.0), Form::Delta, Quantisation::DEFAULT);
    assert_eq!(u16::from_le_bytes([first[6], first[7]]), 0);
    assert!(decode_bin(&first).is_ok());
}

#[test]
fn a_sheet_of_more_than_255_splats_takes_two_bytes() {
    // Accurate: 256 splats. A coarse level keeps the test quick.
    let tile = TileId { z: 4, x: 0, y: 0 };
    let sun = Sun::new(200.0, 50.0).unwrap();
    let prev = shaded(tile, 43200.0 - 320.0, Quality::Accurate, sun);
    let s = shaded(tile, 43200.0, Quality::Accurate, sun);
    let q = Quantisation::DEFAULT;
    let bytes = encode(&s, Form::SelfContained, q);
    // The high bytes of the splat codes have planes of their own.
    assert!(plane_len(&bytes, 1) > 0 && plane_len(&bytes, 7) > 0);
    let d = decode_bin(&bytes).unwrap();
    assert_eq!(d.splat_count, 256);
    assert_eq!(d.records.len(), s.billboards.len());
    for (r, a) in d.records.iter().zip(&s.billboards) {
        assert_eq!(r.ends[0].splat_tau, Some(a.splat_tau));
    }
    let previous = decode_bin(&encode(&prev, Form::SelfContained, q)).unwrap();
    assert_eq!(
        decode_bin_after(&encode(&s, Form::Delta, q), Some(&previous)).unwrap(),
        d
    );
}

/// A small keyframe to break: a coarse tile with few balls.
fn small() -> Vec<u8> {
    encode(
        &fast(TileId { z: 5, x: 0, y: 0 }, 43200.0),
        Form::SelfContained,
        Quantisation::DEFAULT,
    )
}

#[test]
fn truncated_or_damaged_bytes_are_refused_with_a_reason() {
    let bytes = small();
    assert!(decode_bin(&bytes).is_ok());
    for n in 0..bytes.len() {
        let e = decode_bin(&bytes[..n]).unwrap_err();
        assert!(!e.is_empty());
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(decode_bin(&longer).unwrap_err().contains("header says"));
    // Every single byte changed to every value it can hold in the header's tables,
    // and a sample in the planes: an error or a keyframe, never a panic.
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..20_000 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let mut b = bytes.clone();
        let at = (x as usize) % b.len();
        b[at] = (x >> 32) as u8;
        let _ = decode_bin(&b);
    }
    // A lighting no encoder writes (the sun term of the ambient codes is computed from
    // it): colours stay finite and in [0, 2].
    for (at, v) in [
        (116, f32::NAN),
        (92, f32::INFINITY),
        (96, f32::MAX),
        (140, f32::NAN),
        (144, f32::INFINITY),
    ] {
        let mut b = bytes.clone();
        b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        let d = decode_bin(&b).unwrap();
        let colours = d.records.iter().flat_map(|r| r.ends.iter().flat_map(|e| e.colour));
        assert!(colours.into_iter().all(|c| (0.0..=2.0).contains(&c)), "{v} at {at}");
    }
}

#[test]
fn impossible_extents_are_refused_before_allocating() {
    let bytes = small();
    // Level 0's rows and a run set to the most a u32 holds.
    for at in [FIXED_BYTES + 56, FIXED_BYTES + 68] {
        let mut b = bytes.clone();
        b[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode_bin(&b).unwrap_err().contains("impossible extent"));
    }
    let mut b = bytes.clone();
    b[190..192].copy_from_slice(&u16::MAX.to_le_bytes());
    assert!(decode_bin(&b).is_err());
    let mut b = bytes;
    b[188] = 0;
    assert!(decode_bin(&b).is_err(), "no colour bits");
}
