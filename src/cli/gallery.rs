//! `cloudscape gallery`: the fixed views of `bench::gallery` at every quality, written
//! as `<view>-<quality>.png` and `contact.png`, with a table of time, RMSE and SSIM
//! against the reference on stdout.

use clap::Args;

use cloudscape_core::render::scene::parse_size;
use cloudscape_tools::bench::gallery::{QUALITIES, VIEWS, render_gallery};

#[derive(Args)]
pub struct GalleryArgs {
    /// Directory for the PNGs (created if missing); each file is written whole or not at all.
    #[arg(long, default_value = "docs/gallery")]
    out: String,
    /// Size WxH of every picture (default 480x270, or 160x90 with --quick).
    #[arg(long)]
    size: Option<String>,
    /// A quick look: smaller pictures by default.
    #[arg(long)]
    quick: bool,
    /// Samples per pixel of the reference (the path tracer).
    #[arg(long, default_value_t = cloudscape_core::render::pathtrace::DEFAULT_SAMPLES)]
    samples: u32,
    /// Config file (default: the embedded config); the views look at its `default` world.
    #[arg(long)]
    config: Option<String>,
}

pub fn run(a: GalleryArgs) -> Result<(), String> {
    let size = a.size.as_deref().unwrap_or(if a.quick { "160x90" } else { "480x270" });
    let (width, height) = parse_size(size).map_err(|e| format!("--size: {e}"))?;
    // Checked before any work: the reference renderer's own limit refuses larger.
    let cells = VIEWS.len() * QUALITIES.len();
    if width > 1920 || height > 1080 {
        return Err(format!(
            "--size is at most 1920x1080 for a gallery of {cells} pictures, got `{size}`"
        ));
    }
    if a.samples < 2 || a.samples > 4096 {
        return Err(format!("--samples must be between 2 and 4096, got {}", a.samples));
    }
    let config = super::load_config(a.config.as_deref())?;
    std::fs::create_dir_all(&a.out).map_err(|e| format!("cannot create {}: {e}", a.out))?;
    let gallery = render_gallery(&config, width, height, a.samples, |v, q| {
        eprintln!("gallery: {} {}", v.name, q.as_str());
    })?;
    let dir = std::path::Path::new(&a.out);
    for s in &gallery.shots {
        let path = dir.join(format!("{}-{}.png", s.view, s.quality.as_str()));
        super::write_out(&path.to_string_lossy(), &s.png)?;
    }
    super::write_out(&dir.join("contact.png").to_string_lossy(), &gallery.contact)?;
    print!("{}", gallery.table());
    Ok(())
}
