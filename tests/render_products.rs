//! Tile products from an analytic density (three ellipsoidal blobs): they decode with
//! ordinary tools, match their documented shape, hold only finite values, round-trip,
//! and do not depend on the thread count.

use cloudscape_core::density::Grid;
use cloudscape_core::products::{atlas, billboards, coverage, shadow, splats};
use cloudscape_core::render::light::BillboardLight;
use cloudscape_core::render::tile::{ShadedTile, TILE_COLUMNS, TileId, shade_density, tile_halo};
use cloudscape_core::render::{Phase, Quality, ShadingParams, Sun};
use cloudscape_core::world::{Config, Layer};

/// Blob centres in tile columns (x, y) and their radius in columns.
const BLOBS: [(f64, f64, f64); 3] = [(60.0, 60.0, 12.0), (180.0, 90.0, 18.0), (120.0, 200.0, 8.0)];

fn layer() -> Layer {
    Config::embedded().world("default").unwrap().layers[0].clone()
}

/// Density: smooth blobs, 1 at the centre, 0 beyond the radius, over the lower 70 % of the layer.
fn blob_grid(l: &Layer, halo: usize) -> Grid<f32> {
    let n = TILE_COLUMNS + 2 * halo;
    let depth = l.depth as usize;
    let mut g = Grid::<f32>::new(depth, n, n);
    for k in 0..depth {
        let h = (k as f64 + 0.5) / depth as f64;
        for r in 0..n {
            for c in 0..n {
                let (x, y) = (c as f64 + 0.5 - halo as f64, r as f64 + 0.5 - halo as f64);
                let mut v: f64 = 0.0;
                for (bx, by, br) in BLOBS {
                    let d2 = ((x - bx) / br).powi(2) + ((y - by) / br).powi(2) + ((h - 0.35) / 0.35).powi(2);
                    v = v.max((1.0 - d2).max(0.0));
                }
                let i = g.index(k, r, c);
                g.data[i] = v as f32;
            }
        }
    }
    g
}

/// The blob tile shaded at `quality` with the default shading, the sun at `azimuth`
/// and `elevation` (degrees).
fn shaded(quality: Quality, azimuth: f64, elevation: f64) -> ShadedTile {
    shaded_with(quality, Sun::new(azimuth, elevation).unwrap(), ShadingParams::default())
}

fn shaded_with(quality: Quality, sun: Sun, params: ShadingParams) -> ShadedTile {
    let l = layer();
    let tile = TileId { z: 0, x: 3, y: -2 };
    let halo = tile_halo(&l, 0, quality, sun);
    shade_density(0, &l, tile, 1234.0, quality, sun, &params, blob_grid(&l, halo), halo)
}

fn decode_png(bytes: &[u8]) -> (png::OutputInfo, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (info, buf)
}

/// A PNG's colour-space chunks: (its `gAMA` × 100000, whether it has an `sRGB` chunk,
/// whether a `cHRM`).
fn png_space(bytes: &[u8]) -> (Option<u32>, bool, bool) {
    let reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
    let info = reader.info();
    (
        info.gama_chunk.map(|g| g.into_scaled()),
        info.srgb.is_some(),
        info.chrm_chunk.is_some(),
    )
}

fn all_numbers_finite(v: &serde_json::Value) -> bool {
    match v {
        serde_json::Value::Number(n) => n.as_f64().is_some_and(f64::is_finite),
        serde_json::Value::Array(a) => a.iter().all(all_numbers_finite),
        serde_json::Value::Object(o) => o.values().all(all_numbers_finite),
        _ => true,
    }
}

#[test]
fn billboards_json_matches_its_documented_shape() {
    let t = shaded(Quality::Balanced, 135.0, 40.0);
    assert!(t.billboards.len() > 100, "{}", t.billboards.len());
    let v: serde_json::Value = serde_json::from_slice(&billboards::encode_json(&t)).unwrap();
    assert!(all_numbers_finite(&v));
    assert_eq!(v["format"], "cloudscape-billboards");
    assert_eq!(v["quality"], "balanced");
    assert_eq!(v["tile"]["x"], 3);
    assert_eq!(v["tile"]["y"], -2);
    assert_eq!(v["sun"]["bucket"], Sun::new(135.0, 40.0).unwrap().bucket().id());
    assert_eq!(v["count"].as_u64().unwrap() as usize, t.billboards.len());
    let list = v["billboards"].as_array().unwrap();
    assert_eq!(list.len(), t.billboards.len());
    let (x0, y0, size) = (t.origin[0], t.origin[1], t.size);
    assert_eq!((x0, y0), (3.0 * 25_600.0, -2.0 * 25_600.0));
    let splat_count = v["splats"]["count"].as_u64().unwrap();
    let l = layer();
    let band = l.base..=l.base + l.depth as f64 * l.cell_height;
    for b in list {
        let p = b["position"].as_array().unwrap();
        assert_eq!(p.len(), 3);
        let (x, y, z) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap(), p[2].as_f64().unwrap());
        assert!(x >= x0 && x < x0 + size && y >= y0 && y < y0 + size, "{b}");
        assert!(band.contains(&z), "{z} outside the layer's band {band:?}");
        assert_eq!(b["velocity"].as_array().unwrap().len(), 2);
        for end in [&b["start"], &b["end"]] {
            assert!(end["splat"].as_u64().unwrap() < splat_count);
            assert_eq!(end["colour"].as_array().unwrap().len(), 3);
            let a = end["opacity"].as_f64().unwrap();
            let tr = end["sun_transmittance"].as_f64().unwrap();
            assert!((0.0..1.0).contains(&a) && (0.0..=1.0).contains(&tr));
            assert!(
                end["splat_tau"].as_f64().unwrap() > 0.0,
                "a tile of one time has both ends"
            );
        }
        assert_eq!(b["start"], b["end"]);
    }
    assert_eq!(v["keyframe"]["t0"], v["keyframe"]["t1"]);
    // Balls sit only where the blobs are.
    for b in &t.billboards {
        let (cx, cy) = ((b.centre[0] - x0) / 100.0, (b.centre[1] - y0) / 100.0);
        let near = BLOBS
            .iter()
            .any(|(bx, by, br)| ((cx - bx).powi(2) + (cy - by).powi(2)).sqrt() < br + 5.0);
        assert!(near, "ball at ({cx}, {cy}) columns is far from every blob");
    }
}

#[test]
fn billboards_bin_round_trips() {
    let t = shaded(Quality::Fast, 10.0, 60.0);
    let bytes = billboards::encode_bin(&t);
    assert_eq!(
        bytes.len(),
        billboards::BIN_HEADER_BYTES + billboards::BIN_RECORD_BYTES * t.billboards.len()
    );
    assert_eq!(&bytes[0..4], b"CSBB");
    let d = billboards::decode_bin(&bytes).unwrap();
    assert_eq!((d.z, d.x, d.y), (0, 3, -2));
    assert_eq!(d.origin, t.origin);
    assert_eq!(d.records.len(), t.billboards.len());
    assert_eq!(d.splat_count as usize, Quality::Fast.settings().splat_count);
    assert!((d.sun_elevation_deg as f64 - t.sun.elevation_deg).abs() < 1e-4);
    for (r, b) in d.records.iter().zip(&t.billboards) {
        assert!((r.offset[0] as f64 + t.origin[0] - b.centre[0]).abs() < 0.01);
        assert!((r.offset[1] as f64 + t.origin[1] - b.centre[1]).abs() < 0.01);
        assert!((r.offset[2] as f64 - b.centre[2]).abs() < 0.01);
        assert_eq!(r.radius, b.radius);
        // A tile shaded at one time: both ends are that time.
        assert_eq!(r.ends[0], r.ends[1]);
        let e = &r.ends[0];
        assert_eq!(e.splat, b.splat);
        assert_eq!(e.splat_tau, Some(b.splat_tau));
        for c in 0..3 {
            // binary16 keeps 11 significant bits.
            assert!((e.colour[c] - b.colour[c]).abs() <= b.colour[c] / 1024.0, "{e:?} {b:?}");
        }
        assert_eq!(e.opacity, (b.opacity * 255.0).round() as u8);
        assert_eq!(e.sun_transmittance, (b.sun_transmittance * 255.0).round() as u8);
        assert!((e.tau_sun - b.tau_sun).abs() <= b.tau_sun / 1024.0, "{e:?} {b:?}");
        // The transmittance is the exponential of the optical depth.
        assert!((b.sun_transmittance as f64 - (-(b.tau_sun as f64)).exp()).abs() < 1e-6);
    }
    assert!(t.billboards.iter().any(|b| b.tau_sun > 0.5), "some ball is shadowed");
    assert!(billboards::decode_bin(&bytes[..bytes.len() - 1]).is_err());
    assert!(billboards::decode_bin(b"nope").is_err());
}

#[test]
fn shadow_and_coverage_pngs_decode_and_show_the_blobs() {
    // Sun straight overhead: shadows fall right under the blobs.
    let t = shaded(Quality::Balanced, 0.0, 90.0);
    let (info, px) = decode_png(&shadow::encode_png_map(&t));
    assert_eq!(
        (info.width, info.height, info.color_type),
        (256, 256, png::ColorType::Rgb)
    );
    // PNG row 0 is north: tile row r is PNG row 255 − r. R is the span's start, G its
    // end: the same here (one time).
    let at = |x: usize, y: usize| px[((255 - y) * 256 + x) * 3];
    assert!(px.chunks_exact(3).all(|p| p[0] == p[1] && p[2] == 0));
    assert!(at(180, 90) < 200, "under the big blob: {}", at(180, 90));
    assert_eq!(at(5, 250), 255, "clear sky far from blobs");
    let (info, px) = decode_png(&coverage::encode_png_from_grid(&layer(), &t.density, t.halo));
    assert_eq!(
        (info.width, info.height, info.color_type),
        (256, 256, png::ColorType::Rgb)
    );
    let rgb = |x: usize, y: usize| &px[((255 - y) * 256 + x) * 3..((255 - y) * 256 + x) * 3 + 3];
    let c = rgb(60, 60);
    assert!(c[0] > 240 && c[1] > 100 && c[2] > 0, "{c:?}");
    assert_eq!(rgb(5, 250), &[0, 0, 0]);
    // Data maps say linear (gAMA 1.0, no sRGB chunk); pictures say sRGB.
    let linear = (Some(100_000), false, false);
    assert_eq!(png_space(&shadow::encode_png_map(&t)), linear);
    assert_eq!(
        png_space(&coverage::encode_png_from_grid(&layer(), &t.density, t.halo)),
        linear
    );
    assert_eq!(png_space(&splats::encode_png_sheet(Quality::Fast)), linear);
    assert_eq!(png_space(&atlas::build(&t).png), (Some(45_455), true, true));
}

#[test]
fn atlas_png_and_manifest_agree() {
    // Without detail erosion, which may eat a faint fragment whole (it is tested in
    // render::composite): every impostor then shows its billboards.
    let params = ShadingParams {
        light: Some(BillboardLight {
            detail_erosion: 0.0,
            ..Quality::Fast.light()
        }),
        ..ShadingParams::default()
    };
    let t = shaded_with(Quality::Fast, Sun::new(200.0, 25.0).unwrap(), params);
    let a = atlas::build(&t);
    let m: serde_json::Value = serde_json::from_slice(&a.manifest).unwrap();
    assert!(all_numbers_finite(&m));
    assert_eq!(m["format"], "cloudscape-atlas");
    assert_eq!(m["alpha"], "straight");
    let (info, px) = decode_png(&a.png);
    assert_eq!(info.color_type, png::ColorType::Rgba);
    assert_eq!(info.width as u64, m["width"].as_u64().unwrap());
    assert_eq!(info.height as u64, m["height"].as_u64().unwrap());
    let imps = m["impostors"].as_array().unwrap();
    assert_eq!(imps.len(), a.impostors);
    // Three separate blobs: at least three clusters.
    assert!(imps.len() >= 3, "{}", imps.len());
    let total: u64 = imps.iter().map(|i| i["billboards"].as_u64().unwrap()).sum();
    assert_eq!(total as usize, t.billboards.len());
    let mut dense = 0;
    for im in imps {
        let r: Vec<u64> = im["rect"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect();
        assert!(r[0] + r[2] <= info.width as u64 && r[1] + r[3] <= info.height as u64);
        // Some opaque texel inside each rect.
        let mut max_a = 0;
        for y in r[1]..r[1] + r[3] {
            for x in r[0]..r[0] + r[2] {
                max_a = max_a.max(px[((y * info.width as u64 + x) * 4 + 3) as usize]);
            }
        }
        // Edge fragments of a blob may be faint, but never blank.
        assert!(max_a > 0, "impostor {im} is blank");
        dense += (max_a > 100) as usize;
        let size = im["size"].as_array().unwrap();
        assert!(size[0].as_f64().unwrap() > 0.0 && size[1].as_f64().unwrap() > 0.0);
    }
    assert!(dense >= 3, "the three blobs are dense impostors: {dense}");
}

#[test]
fn splat_sheet_png_and_json() {
    let (info, px) = decode_png(&splats::encode_png_sheet(Quality::Accurate));
    assert_eq!(
        (info.width, info.height, info.color_type),
        (16 * 65, 16 * 65, png::ColorType::GrayscaleAlpha)
    );
    let v: serde_json::Value = serde_json::from_slice(&splats::encode_json_sheet(Quality::Accurate)).unwrap();
    assert_eq!(v["count"], 256);
    assert_eq!(v["size"], 65);
    assert_eq!(v["columns"], 16);
    assert_eq!(v["tau"].as_array().unwrap().len(), 256);
    // Centre texel alpha of the last splat ≈ 1 − e^−8; corner texel 0.
    let w = info.width as usize;
    let centre = (15 * 65 + 32) * w + 15 * 65 + 32;
    assert_eq!(px[centre * 2 + 1], 255);
    assert_eq!(px[(15 * 65 * w + 15 * 65) * 2 + 1], 0);
}

#[test]
fn extremes_give_finite_products() {
    let extreme_params = [
        ShadingParams {
            phase: Phase {
                g1: 1.0,
                g2: -1.0,
                mix: 0.5,
            },
            ..ShadingParams::default()
        },
        ShadingParams {
            extinction: f64::INFINITY,
            ..ShadingParams::default()
        },
        ShadingParams {
            extinction: 1e12,
            ..ShadingParams::default()
        },
    ];
    let suns = [
        Sun::new(0.0, 0.0).unwrap(),
        Sun::new(90.0, -30.0).unwrap(),
        Sun::new(0.0, 0.5).unwrap(),
    ];
    for params in extreme_params {
        for sun in suns {
            let t = shaded_with(Quality::Fast, sun, params);
            let v: serde_json::Value = serde_json::from_slice(&billboards::encode_json(&t)).unwrap();
            assert!(all_numbers_finite(&v));
            for b in &t.billboards {
                assert!(b.colour.iter().all(|c| c.is_finite() && (0.0..=2.0).contains(c)));
                assert!(b.tau.is_finite() && (0.0..=1.0).contains(&b.sun_transmittance));
            }
            assert!(t.shadow.iter().all(|s| s.is_finite() && (0.0..=1.0).contains(s)));
            let m: serde_json::Value = serde_json::from_slice(&atlas::build(&t).manifest).unwrap();
            assert!(all_numbers_finite(&m));
        }
    }
    // Zero density: no billboards, a clear shadow map, a valid (1×1) atlas.
    let l = layer();
    let tile = TileId { z: 0, x: 0, y: 0 };
    let sun = Sun::new(0.0, 45.0).unwrap();
    let halo = tile_halo(&l, 0, Quality::Fast, sun);
    let n = TILE_COLUMNS + 2 * halo;
    let empty = Grid::<f32>::new(l.depth as usize, n, n);
    let t = shade_density(
        0,
        &l,
        tile,
        0.0,
        Quality::Fast,
        sun,
        &ShadingParams::default(),
        empty,
        halo,
    );
    assert!(t.billboards.is_empty());
    assert!(t.shadow.iter().all(|&s| s == 1.0));
    let a = atlas::build(&t);
    assert_eq!(a.impostors, 0);
    decode_png(&a.png);
}

#[test]
fn products_do_not_depend_on_the_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let t = shaded(Quality::Balanced, 300.0, 20.0);
            (
                billboards::encode_bin(&t),
                atlas::build(&t).png,
                shadow::encode_png_map(&t),
            )
        })
    };
    assert_eq!(run(1), run(3));
}
