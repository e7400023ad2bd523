//! `cloudscape gallery` through the binary: every view at every quality is written as a
//! PNG of the asked size, the contact sheet is the labelled grid of them (with a column
//! of the viewer's screenshots when asked), the table on stdout has a row per picture,
//! and a second run reads the references from the cache.

use std::process::Command;

use cloudscape_core::world::DEFAULT_CONFIG;

const VIEWS: [&str; 7] = [
    "ground-noon",
    "up-60",
    "above-10km",
    "backlit",
    "sunset",
    "inside-layer",
    "horizon",
];
const QUALITIES: [&str; 4] = ["fast", "balanced", "accurate", "reference"];

/// The embedded config with a cheap `default` world (one thin layer of coarse cells),
/// so the 28 renders take seconds.
fn small_config(dir: &std::path::Path) -> String {
    let base = DEFAULT_CONFIG;
    let presets = &base[..base.find("[worlds.default]").expect("the default world")];
    // A path budget below the quick gallery's reference (32×18 pixels at 32 samples,
    // 18 432 paths): a server's per-request limit, which the offline gallery raises to
    // what its own flags ask for.
    let presets = presets.replace("max_path_samples = 16777216", "max_path_samples = 4096");
    assert!(
        presets.contains("max_path_samples = 4096"),
        "the embedded config sets max_path_samples"
    );
    let world = "[worlds.default]\nseed = 3\n[[worlds.default.layers]]\nname = \"cumulus\"\npreset = \"cumulus\"\nbase = 1200.0\ncell_size = 400.0\ncell_height = 200.0\ndepth = 2\ndt = 20.0\nwind = [6.0, 2.0]\n";
    let path = dir.join("small.toml");
    std::fs::write(&path, format!("{presets}\n{world}")).unwrap();
    path.to_str().unwrap().to_string()
}

/// Width, height and the 8-bit RGB samples of a PNG.
fn png_rgb(path: &std::path::Path) -> (u32, u32, Vec<u8>) {
    let reader = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()))
        .read_info()
        .unwrap_or_else(|e| panic!("{} does not decode: {e}", path.display()));
    let mut reader = reader;
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn png_size(path: &std::path::Path) -> (u32, u32) {
    let (w, h, _) = png_rgb(path);
    (w, h)
}

/// The table row of `view` and `quality` in `stdout`, split into its cells.
fn row<'a>(stdout: &'a str, view: &str, quality: &str) -> Vec<&'a str> {
    stdout
        .lines()
        .find(|l| l.starts_with(&format!("| {view} | {quality} |")))
        .unwrap_or_else(|| panic!("no row for {view} {quality} in\n{stdout}"))
        .split('|')
        .map(str::trim)
        .collect()
}

#[test]
fn a_quick_gallery_writes_every_picture_and_the_contact_sheet() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = small_config(dir.path());
    let out = dir.path().join("gallery");
    let cache = dir.path().join("cache");
    // The viewer took one view only, at another size and shape: a red 48×40 picture.
    let viewer = dir.path().join("browser");
    std::fs::create_dir_all(&viewer).unwrap();
    let red: Vec<u8> = [255u8, 0, 0].repeat(48 * 40);
    let mut png_bytes = Vec::new();
    {
        let mut e = png::Encoder::new(&mut png_bytes, 48, 40);
        e.set_color(png::ColorType::Rgb);
        e.write_header().unwrap().write_image_data(&red).unwrap();
    }
    std::fs::write(viewer.join("gallery-up-60.png"), png_bytes).unwrap();
    let gallery = |out: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_cloudscape"))
            .args([
                "gallery",
                "--quick",
                "--size",
                "32x18",
                "--config",
                &cfg,
                "--viewer-dir",
            ])
            .arg(&viewer)
            .arg("--reference-cache")
            .arg(&cache)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    let o = gallery(&out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("1 of 7 viewer screenshots found"));
    for v in VIEWS {
        for q in QUALITIES {
            assert_eq!(png_size(&out.join(format!("{v}-{q}.png"))), (32, 18), "{v}-{q}");
        }
    }
    // Rows = views, columns = qualities and the viewer: a 150-pixel label column, a
    // 24-pixel header, an 18-pixel caption under each picture.
    let (w, h, sheet) = png_rgb(&out.join("contact.png"));
    assert_eq!((w, h), (150 + 5 * 32, 24 + 7 * (18 + 18)));
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 7 * 4 + 1);
    // The viewer column: the screenshot, scaled and cropped, in its view's row (the
    // second); a grey cell where there is none.
    let centre = |row: usize| {
        let (x, y) = (150 + 4 * 32 + 16, 24 + row * 36 + 9);
        let i = (y * w as usize + x) * 3;
        [sheet[i], sheet[i + 1], sheet[i + 2]]
    };
    assert_eq!(centre(1), [255, 0, 0]);
    assert_eq!(centre(0), [128, 128, 128]);
    // One table row per picture; presets carry RMSE and SSIM against the reference,
    // the reference its split-half SSIM.
    let stdout = String::from_utf8(o.stdout).unwrap();
    for v in VIEWS {
        for q in QUALITIES {
            let cells = row(&stdout, v, q);
            if q == "reference" {
                assert_eq!(cells[4], "–", "{cells:?}");
                let split: f64 = cells[5].strip_prefix("split half ").unwrap().parse().unwrap();
                assert!((-1.0..=1.0).contains(&split), "{cells:?}");
                assert!(!cells[3].contains("cached"), "{cells:?}");
            } else {
                let rmse: f64 = cells[4].parse().unwrap();
                let ssim: f64 = cells[5].parse().unwrap();
                assert!((0.0..=1.0).contains(&rmse) && (-1.0..=1.0).contains(&ssim), "{cells:?}");
            }
        }
    }
    // Again: every reference comes from the cache, the same picture.
    let again = dir.path().join("again");
    let o = gallery(&again);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8(o.stdout).unwrap();
    for v in VIEWS {
        assert!(row(&stdout, v, "reference")[3].ends_with("(cached)"), "{v}");
        let file = format!("{v}-reference.png");
        assert_eq!(
            std::fs::read(out.join(&file)).unwrap(),
            std::fs::read(again.join(&file)).unwrap()
        );
    }
}

#[test]
fn a_missing_viewer_dir_is_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["gallery", "--quick", "--viewer-dir"])
        .arg(dir.path().join("nowhere"))
        .arg("--out")
        .arg(dir.path().join("g"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("--viewer-dir"), "{err}");
    assert!(!dir.path().join("g").exists());
}

#[test]
fn a_bad_size_is_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    for size in ["0x5", "big", "4000x3000"] {
        let o = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
            .args(["gallery", "--size", size, "--out"])
            .arg(dir.path().join("g"))
            .output()
            .unwrap();
        assert!(!o.status.success(), "{size}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains("--size"), "{err}");
        assert!(!dir.path().join("g").exists(), "nothing is written for a bad size");
    }
}
