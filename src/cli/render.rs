//! `cloudscape render`: what a client would see from a camera, as a PNG. With
//! `--quality reference` the path tracer's stated noise goes to stderr (and into the
//! PNG's text chunks).

use clap::Args;

use cloudscape_client::TileClient;
use cloudscape_core::render::pathtrace::DEFAULT_SAMPLES;
use cloudscape_core::render::scene::{RenderRequest, parse_size};
use cloudscape_core::render::{Camera, Phase, Quality, ShadingParams, Sun};
use cloudscape_core::view::render;

#[derive(Args)]
pub struct RenderArgs {
    /// World name from the config, or a decimal u64 seed (default climate).
    #[arg(long)]
    world: String,
    /// Camera X,Y,Z,YAW,PITCH,FOV: metres; yaw clockwise from north; pitch above the
    /// horizon; horizontal field of view; degrees.
    #[arg(long, allow_hyphen_values = true)]
    camera: String,
    /// World-clock time in seconds, 0 <= t <= 1e12.
    #[arg(long, allow_hyphen_values = true)]
    t: String,
    /// Image size WxH in pixels.
    #[arg(long)]
    size: String,
    /// fast | balanced | accurate (billboards) | reference (volumetric path tracer,
    /// every order of scattering) | reference-single (single-scattering ray marcher).
    #[arg(long, default_value = "balanced")]
    quality: String,
    /// Samples per pixel of `--quality reference`, at least 2 (default 32). Its noise
    /// falls as 1/√samples; the render prints it on stderr.
    #[arg(long)]
    samples: Option<u32>,
    /// Sun AZ,EL in degrees (default: from the world clock and the config's latitude and day).
    #[arg(long, allow_hyphen_values = true)]
    sun: Option<String>,
    /// Dual Henyey–Greenstein phase function G1,G2,MIX (default 0.7,-0.2,0.5).
    #[arg(long, allow_hyphen_values = true)]
    phase: Option<String>,
    /// Config file (default: the embedded config). Not used with --server.
    #[arg(long)]
    config: Option<String>,
    /// Draw what the server at URL (http://HOST:PORT) serves: fetch its billboard tiles,
    /// shadow maps and splats over HTTP and composite them here, instead of simulating.
    #[arg(long)]
    server: Option<String>,
    /// Output PNG, `-` for stdout. A regular file is replaced whole or not at all;
    /// a symlink is followed; a FIFO or device is written in place.
    #[arg(long)]
    out: String,
}

pub fn run(a: RenderArgs) -> Result<(), String> {
    let t: f64 =
        a.t.trim()
            .parse()
            .map_err(|_| format!("--t is not a number: `{}`", a.t))?;
    let camera = Camera::parse(&a.camera).map_err(|e| format!("--camera: {e}"))?;
    let (width, height) = parse_size(&a.size).map_err(|e| format!("--size: {e}"))?;
    let quality = Quality::parse(&a.quality).ok_or_else(|| {
        format!(
            "--quality must be fast, balanced, accurate, reference or reference-single, got `{}`",
            a.quality
        )
    })?;
    if a.samples.is_some() && quality != Quality::Reference {
        return Err(format!(
            "--samples applies to --quality reference (the path tracer) only, not `{}`",
            quality.as_str()
        ));
    }
    let sun = match &a.sun {
        Some(s) => Some(Sun::parse(s).map_err(|e| format!("--sun: {e}"))?),
        None => None,
    };
    let mut params = ShadingParams::default();
    if let Some(p) = &a.phase {
        let v = super::parse_numbers("--phase", p, 3)?;
        if v[0].abs() > 1.0 || v[1].abs() > 1.0 || !(0.0..=1.0).contains(&v[2]) {
            return Err(format!(
                "--phase needs G1,G2 within [-1, 1] and MIX within [0, 1], got `{p}`"
            ));
        }
        params.phase = Phase {
            g1: v[0],
            g2: v[1],
            mix: v[2],
        };
    }
    let req = RenderRequest {
        camera,
        width,
        height,
        t,
        quality,
        sun,
        params,
        samples: a.samples.unwrap_or(DEFAULT_SAMPLES),
    };
    let rendered = match &a.server {
        Some(url) => TileClient::new(url)
            .and_then(|mut client| {
                // One picture: nothing to animate, so no next keyframes.
                client.set_prefetch(false);
                client.render(&a.world, &req)
            })
            .map_err(|e| e.to_string())?,
        None => {
            let config = super::load_config(a.config.as_deref())?;
            let world = config
                .world(&a.world)
                .ok_or_else(|| format!("unknown world `{}`", a.world))?;
            render(&world, &config, &req).map_err(|e| e.to_string())?
        }
    };
    match rendered.noise {
        Some(noise) => {
            super::write_out(&a.out, &rendered.image.to_png_with_noise(&noise))?;
            eprintln!(
                "reference: {} samples per pixel, noise {:.5} (mean standard error of pixel luminance; {:.2} % of the mean luminance {:.4})",
                noise.samples,
                noise.std_error,
                100.0 * noise.relative(),
                noise.mean_luminance
            );
            Ok(())
        }
        None => super::write_out(&a.out, &rendered.image.to_png()),
    }
}
