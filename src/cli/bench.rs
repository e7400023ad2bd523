//! `cloudscape bench`: runs the measurements of `cloudscape_tools::bench` and writes their
//! sections into BENCHMARKS.md (between generated-section markers) and the plots.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use cloudscape_tools::bench::quality::{QualitySetup, ReferenceCache};
use cloudscape_tools::bench::{self, Effort};

#[derive(Args)]
pub struct BenchArgs {
    /// Smaller sizes and budgets: about a minute on a 2-core machine.
    #[arg(long)]
    quick: bool,
    /// The smallest sizes that still run every section (CI smoke test).
    #[arg(long, hide = true, conflicts_with = "quick")]
    smoke: bool,
    /// The Markdown file whose generated sections are replaced (created if missing).
    #[arg(long, default_value = "BENCHMARKS.md")]
    out: String,
    /// Directory for the PNG plots (default: `bench/` beside the Markdown file).
    #[arg(long)]
    plots: Option<String>,
    /// Measure only these sections (comma-separated: machine, automaton, fields,
    /// tiles, encoders, quality, http, rosa, scaling, keyframes, stages, precipitation-day, wire);
    /// the others are left as they are.
    #[arg(long, value_delimiter = ',')]
    only: Option<Vec<String>>,
    /// The quality section on these views only (comma-separated names of the scene set,
    /// as `stratus-deck-from-below`, or of the gallery, as `ground-noon`).
    #[arg(long, value_delimiter = ',')]
    quality_views: Option<Vec<String>>,
    /// Directory where the quality section keeps its reference renders between runs
    /// (keyed by view, size, samples, ALGORITHM_VERSION and the scene's inputs).
    #[arg(long, default_value = "target/quality-ref")]
    reference_cache: String,
    /// Path-trace every reference again (nothing read from or written to the cache).
    #[arg(long)]
    no_reference_cache: bool,
}

/// `to` relative to directory `from` when `to` is inside it, else `to` as given.
fn link(from: &Path, to: &Path) -> String {
    let rel = to.strip_prefix(from).unwrap_or(to);
    let s = rel.to_string_lossy().replace('\\', "/");
    if s.is_empty() { ".".into() } else { s }
}

pub fn run(a: BenchArgs) -> Result<(), String> {
    let effort = if a.smoke {
        Effort::Smoke
    } else if a.quick {
        Effort::Quick
    } else {
        Effort::Full
    };
    let mut quality = QualitySetup::for_effort(effort);
    if let Some(views) = &a.quality_views {
        quality = quality.only_views(views).map_err(|e| format!("--quality-views: {e}"))?;
    }
    if !a.no_reference_cache {
        quality = quality.with_cache(ReferenceCache::new(&a.reference_cache));
    }
    let out = PathBuf::from(&a.out);
    let out_dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let plots = a.plots.map(PathBuf::from).unwrap_or_else(|| out_dir.join("bench"));
    // Fail on broken markers before spending minutes measuring.
    bench::check_markers(&read_document(&out)?)?;
    std::fs::create_dir_all(&plots).map_err(|e| format!("cannot create {}: {e}", plots.display()))?;

    let start = Instant::now();
    let run = bench::run(effort, a.only.as_deref(), &quality, |name| {
        eprintln!("[{:>6.1} s] bench: {name}", start.elapsed().as_secs_f64());
    })?;
    let prefix = link(&out_dir, &plots);
    let sections: Vec<_> = run
        .sections
        .into_iter()
        .map(|mut s| {
            s.markdown = s.markdown.replace("@plots@", &prefix);
            s
        })
        .collect();
    for p in &run.plots {
        let path = plots.join(&p.file);
        super::write_out(&path.to_string_lossy(), &p.bytes)?;
    }
    // Read again just before writing: prose edited while the run measured (minutes)
    // is kept. If an edit broke the markers, the measured sections go to a file of
    // their own rather than being lost.
    let merged = match bench::merge_sections(&read_document(&out)?, &sections) {
        Ok(m) => m,
        Err(e) => {
            let side = format!("{}.sections.md", a.out);
            let fresh = bench::merge_sections("", &sections)?;
            super::write_out(&side, fresh.as_bytes())?;
            return Err(format!("{e}; {} left unchanged, the sections are in {side}", a.out));
        }
    };
    super::write_out(&a.out, merged.as_bytes())?;
    eprintln!(
        "[{:>6.1} s] bench: wrote {} sections to {} and {} plots to {}",
        start.elapsed().as_secs_f64(),
        sections.len(),
        a.out,
        run.plots.len(),
        plots.display()
    );
    Ok(())
}

/// The Markdown file the sections go into (a new one if there is none).
fn read_document(out: &Path) -> Result<String, String> {
    match std::fs::read_to_string(out) {
        Ok(s) => Ok(s),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok("# Benchmarks\n".to_string()),
        Err(e) => Err(format!("cannot read {}: {e}", out.display())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_links_are_relative_to_the_markdown() {
        assert_eq!(link(Path::new("."), Path::new("./bench")), "bench");
        assert_eq!(link(Path::new("/tmp/x"), Path::new("/tmp/x/plots")), "plots");
        assert_eq!(link(Path::new("/tmp/x"), Path::new("/elsewhere")), "/elsewhere");
    }
}
