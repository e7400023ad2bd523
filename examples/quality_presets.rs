//! The "speed against accuracy" section of `cloudscape bench` alone, printed as
//! Markdown (the bench writes it into BENCHMARKS.md; this only prints):
//!
//!     cargo run --release --example quality_presets -- [smoke|quick|full]

use cloudscape_tools::bench::{BenchRun, Effort, quality};

fn main() -> Result<(), String> {
    let effort = match std::env::args().nth(1).as_deref() {
        Some("smoke") => Effort::Smoke,
        Some("full") => Effort::Full,
        None | Some("quick") => Effort::Quick,
        Some(other) => return Err(format!("effort must be smoke | quick | full, got `{other}`")),
    };
    let mut run = BenchRun::default();
    let setup = quality::QualitySetup::for_effort(effort);
    quality::speed_accuracy(&setup, &mut run, &mut |m| eprintln!("{m}"))?;
    for s in &run.sections {
        println!("## {}\n\n{}", s.title, s.markdown);
    }
    Ok(())
}
