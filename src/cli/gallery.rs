//! `cloudscape gallery`: the fixed views of `bench::gallery` at every quality, written
//! as `<view>-<quality>.png` and `contact.png` (with a column of the viewer's
//! screenshots when `--viewer-dir` is given), with the quality table of every view
//! and preset against the reference on stdout.

use std::path::PathBuf;

use clap::Args;

use cloudscape_core::render::scene::parse_size;
use cloudscape_tools::bench::gallery::{GallerySetup, QUALITIES, VIEWS, render_gallery};
use cloudscape_tools::bench::quality::ReferenceCache;

#[derive(Args)]
pub struct GalleryArgs {
    /// Directory for the PNGs (created if missing); each file is written whole or not at all.
    #[arg(long, default_value = "docs/gallery")]
    out: String,
    /// Size WxH of every picture (default 640x360, or 160x90 with --quick).
    #[arg(long)]
    size: Option<String>,
    /// A quick look: smaller pictures and a 32-spp reference by default.
    #[arg(long)]
    quick: bool,
    /// Samples per pixel of the reference (the path tracer), both halves together
    /// (default 256, or 32 with --quick).
    #[arg(long)]
    samples: Option<u32>,
    /// Config file (default: the embedded config); the views look at its `default` world.
    #[arg(long)]
    config: Option<String>,
    /// Directory of the viewer's screenshots `gallery-<view>.png` (the browser suite
    /// writes them to target/browser/): a column of the contact sheet.
    #[arg(long)]
    viewer_dir: Option<String>,
    /// Directory where reference renders are kept between runs.
    #[arg(long, default_value = "target/quality-ref")]
    reference_cache: String,
    /// Path-trace every reference again (nothing read from or written to the cache).
    #[arg(long)]
    no_reference_cache: bool,
}

pub fn run(a: GalleryArgs) -> Result<(), String> {
    let size = a.size.as_deref().unwrap_or(if a.quick { "160x90" } else { "640x360" });
    let (width, height) = parse_size(size).map_err(|e| format!("--size: {e}"))?;
    // Checked before any work: the reference renderer's own limit refuses larger.
    let cells = VIEWS.len() * QUALITIES.len();
    if width > 1920 || height > 1080 {
        return Err(format!(
            "--size is at most 1920x1080 for a gallery of {cells} pictures, got `{size}`"
        ));
    }
    let samples = a.samples.unwrap_or(if a.quick { 32 } else { 256 });
    if !(4..=4096).contains(&samples) {
        return Err(format!("--samples must be between 4 and 4096, got {samples}"));
    }
    if let Some(d) = &a.viewer_dir
        && !std::path::Path::new(d).is_dir()
    {
        return Err(format!("--viewer-dir: {d} is not a directory"));
    }
    let config = super::load_config(a.config.as_deref())?;
    std::fs::create_dir_all(&a.out).map_err(|e| format!("cannot create {}: {e}", a.out))?;
    let setup = GallerySetup {
        size: (width, height),
        samples,
        viewer_dir: a.viewer_dir.map(PathBuf::from),
        cache: (!a.no_reference_cache).then(|| ReferenceCache::new(&a.reference_cache)),
    };
    let gallery = render_gallery(&config, &setup, |v, q| {
        eprintln!("gallery: {} {}", v.name, q.as_str());
    })?;
    let dir = std::path::Path::new(&a.out);
    for s in &gallery.shots {
        let path = dir.join(format!("{}-{}.png", s.view, s.quality.as_str()));
        super::write_out(&path.to_string_lossy(), &s.png)?;
    }
    super::write_out(&dir.join("contact.png").to_string_lossy(), &gallery.contact)?;
    if let Some(n) = gallery.viewer_found {
        eprintln!("gallery: {n} of {} viewer screenshots found", VIEWS.len());
    }
    print!("{}", gallery.table());
    Ok(())
}
