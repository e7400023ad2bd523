//! `cloudscape gallery` through the binary: every view at every quality is written as a
//! PNG of the asked size, the contact sheet is the labelled grid of them, and the table
//! on stdout has a row per picture.

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
    let world = "[worlds.default]\nseed = 3\n[[worlds.default.layers]]\nname = \"cumulus\"\npreset = \"cumulus\"\nbase = 1200.0\ncell_size = 400.0\ncell_height = 200.0\ndepth = 2\ndt = 20.0\nwind = [6.0, 2.0]\n";
    let path = dir.join("small.toml");
    std::fs::write(&path, format!("{presets}\n{world}")).unwrap();
    path.to_str().unwrap().to_string()
}

fn png_size(path: &std::path::Path) -> (u32, u32) {
    let reader = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()))
        .read_info()
        .unwrap_or_else(|e| panic!("{} does not decode: {e}", path.display()));
    let mut reader = reader;
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    (info.width, info.height)
}

#[test]
fn a_quick_gallery_writes_every_picture_and_the_contact_sheet() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = small_config(dir.path());
    let out = dir.path().join("gallery");
    let o = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["gallery", "--quick", "--size", "32x18", "--config", &cfg, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for v in VIEWS {
        for q in QUALITIES {
            assert_eq!(png_size(&out.join(format!("{v}-{q}.png"))), (32, 18), "{v}-{q}");
        }
    }
    // Rows = views, columns = qualities: a 150-pixel label column, a 24-pixel header,
    // an 18-pixel caption under each picture.
    assert_eq!(png_size(&out.join("contact.png")), (150 + 4 * 32, 24 + 7 * (18 + 18)));
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 7 * 4 + 1);
    // One table row per picture; presets carry RMSE and SSIM against the reference.
    let stdout = String::from_utf8(o.stdout).unwrap();
    for v in VIEWS {
        for q in QUALITIES {
            let row = stdout
                .lines()
                .find(|l| l.starts_with(&format!("| {v} | {q} |")))
                .unwrap_or_else(|| panic!("no row for {v} {q} in\n{stdout}"));
            let cells: Vec<&str> = row.split('|').map(str::trim).collect();
            if q == "reference" {
                assert_eq!((cells[4], cells[5]), ("–", "–"), "{row}");
            } else {
                let rmse: f64 = cells[4].parse().unwrap();
                let ssim: f64 = cells[5].parse().unwrap();
                assert!((0.0..=1.0).contains(&rmse) && (-1.0..=1.0).contains(&ssim), "{row}");
            }
        }
    }
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
