//! `cloudscape bench`: the measurements behind BENCHMARKS.md, as a library.
//!
//! Each section measures one claim and returns a Markdown fragment (and plots);
//! [`merge_sections`] writes the fragments between generated-section markers in
//! BENCHMARKS.md, leaving the hand-written prose outside the markers alone:
//!
//! ```text
//! <!-- bench:automaton:begin -->  …generated…  <!-- bench:automaton:end -->
//! ```
//!
//! Sections: the machine, automaton (packed vs naive), fields (ours vs the `noise`
//! crate), tile pipeline per quality preset (cold and warm), encoders, speed against
//! accuracy of the presets, HTTP (warm and cold, in-process server on loopback), the
//! grid sizes of Rosa 2013 Table 5.1, scaling (region area, level, t), keyframes, and
//! the precipitation of a storm over a day as a user's `/series` queries answer it.
//!
//! The quality section's size, reference samples and views are its own
//! ([`quality::QualitySetup`]); its reference renders can be kept on disk.
//!
//! Times are wall-clock medians over repeated runs (at least one) within a budget per
//! measurement; [`Effort`] sets sizes and budgets. Ratios in a table are measured in
//! the same run, side by side.

pub mod core;
pub mod gallery;
mod http;
mod keyframes;
mod pipeline;
pub mod quality;
mod stages;
mod weather;
pub mod wire;

use std::time::{Duration, Instant};

use cloudscape_core::civil::civil_from_days;

/// How hard to measure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effort {
    /// The smallest sizes that still run every section (CI smoke, seconds).
    Smoke,
    /// About a minute on the 2-core project machine.
    Quick,
    /// The published figures (about 5 minutes on the 2-core project machine, 2 of
    /// them the precipitation day's 1441 `/series` points).
    Full,
}

impl Effort {
    pub fn name(self) -> &'static str {
        match self {
            Effort::Smoke => "smoke",
            Effort::Quick => "quick",
            Effort::Full => "full",
        }
    }

    /// Time budget of one measurement (it always runs at least once).
    fn budget(self) -> Duration {
        match self {
            Effort::Smoke => Duration::from_millis(50),
            Effort::Quick => Duration::from_millis(400),
            Effort::Full => Duration::from_secs(4),
        }
    }

    /// Largest number of repetitions of one measurement.
    fn max_iters(self) -> usize {
        match self {
            Effort::Smoke => 2,
            Effort::Quick => 5,
            Effort::Full => 30,
        }
    }
}

/// One generated section of BENCHMARKS.md.
#[derive(Clone, Debug)]
pub struct Section {
    /// Marker id (`<!-- bench:ID:begin -->`).
    pub id: &'static str,
    /// Heading shown when the section is appended for the first time.
    pub title: &'static str,
    /// The generated fragment; `@plots@` stands for the plots directory.
    pub markdown: String,
}

/// A file written to the plots directory: a PNG plot, or the data behind one (CSV).
#[derive(Clone, Debug)]
pub struct Plot {
    /// File name within the plots directory.
    pub file: String,
    /// Its contents.
    pub bytes: Vec<u8>,
}

/// Everything one `cloudscape bench` run produced.
#[derive(Clone, Debug, Default)]
pub struct BenchRun {
    /// The sections measured, in the order they ran.
    pub sections: Vec<Section>,
    /// The files their fragments link to.
    pub plots: Vec<Plot>,
}

impl BenchRun {
    /// Adds the section `id` (`<!-- bench:ID:begin -->`) with its heading and fragment.
    pub fn add_section(&mut self, id: &'static str, title: &'static str, markdown: String) {
        self.sections.push(Section { id, title, markdown });
    }

    /// Adds the file `file` to the plots directory.
    pub fn add_plot(&mut self, file: &str, bytes: Vec<u8>) {
        self.plots.push(Plot {
            file: file.to_string(),
            bytes,
        });
    }
}

/// A timed measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timing {
    pub iters: usize,
    pub median_s: f64,
    pub min_s: f64,
}

/// Runs `f` at least once and then again while within `effort`'s budget.
pub fn time(effort: Effort, mut f: impl FnMut()) -> Timing {
    time_with(effort.budget(), effort.max_iters(), &mut || {
        let t = Instant::now();
        f();
        t.elapsed()
    })
}

/// [`time`] for `f` on a fresh input from `setup` each time; only `f` is timed.
/// Each input is made right before its timed call, so it is warm in cache (as
/// criterion's `iter_batched_ref` with `BatchSize::PerIteration`). The budget
/// counts the setup too.
pub fn time_batched<I>(effort: Effort, mut setup: impl FnMut() -> I, mut f: impl FnMut(&mut I)) -> Timing {
    time_with(effort.budget(), effort.max_iters(), &mut || {
        let mut input = setup();
        let t = Instant::now();
        f(&mut input);
        let spent = t.elapsed();
        std::hint::black_box(&input);
        spent
    })
}

/// `run` returns the time of the part it measures.
fn time_with(budget: Duration, max_iters: usize, run: &mut dyn FnMut() -> Duration) -> Timing {
    let start = Instant::now();
    let mut samples = Vec::new();
    while samples.is_empty() || (start.elapsed() < budget && samples.len() < max_iters) {
        samples.push(run().as_secs_f64());
    }
    samples.sort_by(f64::total_cmp);
    Timing {
        iters: samples.len(),
        median_s: samples[samples.len() / 2],
        min_s: samples[0],
    }
}

/// A duration for a table: ms below 1 s, s above.
pub fn fmt_s(s: f64) -> String {
    if s < 1e-3 {
        format!("{:.1} µs", s * 1e6)
    } else if s < 1.0 {
        format!("{:.1} ms", s * 1e3)
    } else {
        format!("{s:.2} s")
    }
}

/// A rate in scientific notation, `1.9×10^8`.
pub fn fmt_rate(r: f64) -> String {
    if !(r.is_finite() && r > 0.0) {
        return "–".into();
    }
    let e = r.log10().floor();
    format!("{:.1}×10^{}", r / 10f64.powf(e), e as i32)
}

/// One section of a run: it measures, adds its tables to the run and may report
/// its progress (the long ones do).
type SectionFn<'a> = Box<dyn FnOnce(&mut BenchRun, &mut dyn FnMut(&str)) -> Result<(), String> + 'a>;

/// Names of the sections [`run`] measures, in order (what `bench --only` accepts).
pub const SECTION_NAMES: [&str; 13] = [
    "machine",
    "automaton",
    "fields",
    "tiles",
    "encoders",
    "quality",
    "http",
    "rosa",
    "scaling",
    "keyframes",
    "stages",
    "precipitation-day",
    "wire",
];

/// Runs every section (or, with `only`, those of [`SECTION_NAMES`] it names), the
/// quality section as `quality` sets it up, and reports each one's name to
/// `progress` as it starts (and the quality section each view).
pub fn run(
    effort: Effort,
    only: Option<&[String]>,
    quality: &quality::QualitySetup,
    mut progress: impl FnMut(&str),
) -> Result<BenchRun, String> {
    if let Some(names) = only
        && let Some(bad) = names.iter().find(|n| !SECTION_NAMES.contains(&n.as_str()))
    {
        return Err(format!(
            "no bench section `{bad}` (sections: {})",
            SECTION_NAMES.join(", ")
        ));
    }
    let mut out = BenchRun::default();
    let steps: [(&str, SectionFn); 13] = [
        (
            "machine",
            Box::new(|o, _| {
                o.sections.push(machine(effort));
                Ok(())
            }),
        ),
        ("automaton", Box::new(|o, _| core::automaton(effort, o))),
        ("fields", Box::new(|o, _| core::fields(effort, o))),
        ("tile pipeline", Box::new(|o, _| pipeline::tiles(effort, o))),
        ("encoders", Box::new(|o, _| pipeline::encoders(effort, o))),
        (
            "quality presets",
            Box::new(|o, p| quality::speed_accuracy(quality, o, p)),
        ),
        ("http", Box::new(|o, _| http::http(effort, o))),
        ("rosa 2013", Box::new(|o, _| pipeline::rosa(effort, o))),
        ("scaling", Box::new(|o, _| core::scaling(effort, o))),
        ("keyframes", Box::new(|o, _| keyframes::keyframes(effort, o))),
        ("keyframe stages", Box::new(|o, _| stages::stages(effort, o))),
        (
            "precipitation over a day",
            Box::new(|o, _| weather::precipitation_day(effort, o)),
        ),
        ("bytes on the wire", Box::new(|o, _| wire::wire(effort, o))),
    ];
    for ((name, step), id) in steps.into_iter().zip(SECTION_NAMES) {
        if only.is_some_and(|names| !names.iter().any(|n| n == id)) {
            continue;
        }
        progress(name);
        step(&mut out, &mut progress).map_err(|e| format!("bench section {name}: {e}"))?;
    }
    Ok(out)
}

fn begin(id: &str) -> String {
    format!("<!-- bench:{id}:begin -->")
}

fn end(id: &str) -> String {
    format!("<!-- bench:{id}:end -->")
}

/// Heading under which sections without markers are appended.
const GENERATED_HEADING: &str = "## Generated by `cloudscape bench`";

/// The lines of `document` (line endings included), each with where it starts.
/// Markers and the heading are matched on a line's text trimmed of its ending and
/// surrounding spaces: a marker is a line of its own, so prose may quote one (as
/// BENCHMARKS.md's heading does).
fn lines_at(document: &str) -> impl Iterator<Item = (usize, &str)> {
    let mut at = 0;
    document.split_inclusive('\n').map(move |line| {
        let start = at;
        at += line.len();
        (start, line)
    })
}

/// The section id of a marker line (`<!-- bench:ID:begin -->` or `…:end -->`).
fn marker_id(line: &str) -> Option<&str> {
    let rest = line.strip_prefix("<!-- bench:")?.strip_suffix(" -->")?;
    rest.strip_suffix(":begin").or_else(|| rest.strip_suffix(":end"))
}

/// Where `marker` stands in the lines that are `marker` (spaces around it are kept).
fn marker_lines(document: &str, marker: &str) -> Vec<std::ops::Range<usize>> {
    lines_at(document)
        .filter(|(_, line)| line.trim() == marker)
        .map(|(at, line)| {
            let start = at + line.len() - line.trim_start().len();
            start..start + marker.len()
        })
        .collect()
}

/// The error for a section whose markers do not pair up.
fn broken(id: &str) -> String {
    format!(
        "the markers of section `{id}` are broken (need one `{}` line before one `{}` line)",
        begin(id),
        end(id)
    )
}

/// Checks that every generated-section marker line in `document` pairs up: each
/// `<!-- bench:ID:begin -->` once, followed by its `<!-- bench:ID:end -->`.
pub fn check_markers(document: &str) -> Result<(), String> {
    for (_, line) in lines_at(document) {
        let Some(id) = marker_id(line.trim()) else { continue };
        match (
            marker_lines(document, &begin(id)).as_slice(),
            marker_lines(document, &end(id)).as_slice(),
        ) {
            ([b], [e]) if b.start < e.start => {}
            _ => return Err(broken(id)),
        }
    }
    Ok(())
}

/// `document` with each section's text between its markers replaced; a section whose
/// markers are missing is appended (under [`GENERATED_HEADING`]) with its title.
/// Everything outside the markers is kept byte for byte.
pub fn merge_sections(document: &str, sections: &[Section]) -> Result<String, String> {
    check_markers(document)?;
    let mut doc = document.to_string();
    for s in sections {
        let (b, e) = (begin(s.id), end(s.id));
        let body = format!("{b}\n{}\n{e}", s.markdown.trim_end());
        match (marker_lines(&doc, &b).first(), marker_lines(&doc, &e).first()) {
            (Some(bl), Some(el)) if bl.start < el.start => doc.replace_range(bl.start..el.end, &body),
            (None, None) => {
                if !lines_at(&doc).any(|(_, l)| l.trim() == GENERATED_HEADING) {
                    if !doc.is_empty() && !doc.ends_with('\n') {
                        doc.push('\n');
                    }
                    doc.push_str(&format!("\n{GENERATED_HEADING}\n"));
                }
                doc.push_str(&format!("\n### {}\n\n{body}\n", s.title));
            }
            _ => return Err(broken(s.id)),
        }
    }
    Ok(doc)
}

/// The machine: cores, CPU model, memory, load, date, effort.
fn machine(effort: Effort) -> Section {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpuinfo
        .lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split(':').nth(1))
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|| "unknown".into());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mem_gib = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| {
            m.lines()
                .find(|l| l.starts_with("MemTotal:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map(|kib| format!("{:.0} GiB", kib / 1024.0 / 1024.0))
        .unwrap_or_else(|| "unknown".into());
    let load = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|| "unknown".into());
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs() as i64);
    let markdown = format!(
        "| | |\n|---|---|\n| run | `cloudscape bench` ({}), {} UTC |\n| cores | {cores} (rayon threads: {}) |\n| CPU | {model} |\n| memory | {mem_gib} |\n| load average at the start (1, 5, 15 min) | {load} |\n| build | {} |\n",
        effort.name(),
        utc(secs),
        rayon::current_num_threads(),
        if cfg!(debug_assertions) {
            "debug (times are not representative)"
        } else {
            "release"
        },
    );
    Section {
        id: "machine",
        title: "Machine",
        markdown,
    }
}

/// `YYYY-MM-DD HH:MM` of Unix seconds.
fn utc(secs: i64) -> String {
    let (y, m, d) = civil_from_days(secs.div_euclid(86_400));
    let rem = secs.rem_euclid(86_400);
    format!("{y:04}-{m:02}-{d:02} {:02}:{:02}", rem / 3600, rem % 3600 / 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(id: &'static str, text: &str) -> Section {
        Section {
            id,
            title: "T",
            markdown: text.into(),
        }
    }

    #[test]
    fn sections_replace_between_markers_and_keep_prose() {
        let doc = "# B\n\nprose\n<!-- bench:a:begin -->\nold\n<!-- bench:a:end -->\nmore prose\n";
        let out = merge_sections(doc, &[section("a", "new\n")]).unwrap();
        assert_eq!(
            out,
            "# B\n\nprose\n<!-- bench:a:begin -->\nnew\n<!-- bench:a:end -->\nmore prose\n"
        );
        // A new section is appended once under the generated heading; a rerun is stable.
        let out2 = merge_sections(&out, &[section("b", "x")]).unwrap();
        assert!(out2.starts_with(&out) && out2.contains(GENERATED_HEADING) && out2.contains("### T"));
        assert_eq!(merge_sections(&out2, &[section("b", "x")]).unwrap(), out2);
        assert!(merge_sections("<!-- bench:a:end -->\n<!-- bench:a:begin -->\n", &[section("a", "")]).is_err());
        assert!(check_markers("<!-- bench:z:end -->\n<!-- bench:z:begin -->").is_err());
        assert!(check_markers("<!-- bench:z:begin -->").is_err());
        assert!(check_markers("<!-- bench:z:begin -->\n<!-- bench:z:end -->\n<!-- bench:z:begin -->\n").is_err());
        assert!(check_markers(&out2).is_ok());
        assert!(
            check_markers("<!-- bench:z:begin -->\n<!-- bench:z:end -->\n<!-- bench:z:end -->\n").is_err(),
            "a second end line"
        );
    }

    #[test]
    fn markers_are_lines_whatever_their_ending_and_spaces() {
        // CRLF line endings, spaces around a marker, an end marker with no newline
        // at the end of the file: still markers, replaced in place, prose kept.
        let doc = "# B\r\n  <!-- bench:a:begin -->\r\nold\r\n<!-- bench:a:end -->  \r\ntail\r\n\
                   <!-- bench:b:begin -->\nold\n<!-- bench:b:end -->";
        let out = merge_sections(doc, &[section("a", "new"), section("b", "new")]).unwrap();
        assert_eq!(
            out,
            "# B\r\n  <!-- bench:a:begin -->\nnew\n<!-- bench:a:end -->  \r\ntail\r\n\
             <!-- bench:b:begin -->\nnew\n<!-- bench:b:end -->"
        );
        assert!(!out.contains(GENERATED_HEADING), "nothing appended");
        // Prose that quotes the generated heading does not stand for it.
        let quoted = format!("see `{GENERATED_HEADING}` below\n");
        let out = merge_sections(&quoted, &[section("c", "x")]).unwrap();
        assert!(out.contains(&format!("\n{GENERATED_HEADING}\n")), "{out}");
    }

    #[test]
    fn prose_may_quote_a_marker() {
        // A marker counts only as a line of its own: prose that quotes one (inline,
        // or with a placeholder id) neither breaks the check nor is replaced.
        let doc = "between the `<!-- bench:ID:begin/end -->` markers and `<!-- bench:a:begin -->`\n\
                   <!-- bench:a:begin -->\nold\n<!-- bench:a:end -->\n";
        let out = merge_sections(doc, &[section("a", "new")]).unwrap();
        assert_eq!(
            out,
            "between the `<!-- bench:ID:begin/end -->` markers and `<!-- bench:a:begin -->`\n\
             <!-- bench:a:begin -->\nnew\n<!-- bench:a:end -->\n"
        );
    }

    #[test]
    fn the_repository_benchmarks_file_can_be_rewritten() {
        // `cloudscape bench` refused this file once, because its prose quoted a marker.
        let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../BENCHMARKS.md")).unwrap();
        check_markers(&doc).unwrap();
        let out = merge_sections(&doc, &[section("automaton", "x")]).unwrap();
        assert!(out.contains("<!-- bench:automaton:begin -->\nx\n<!-- bench:automaton:end -->"));
    }

    #[test]
    fn dates_and_numbers_format() {
        assert_eq!(utc(0), "1970-01-01 00:00");
        assert_eq!(utc(1_700_000_000), "2023-11-14 22:13");
        assert_eq!(fmt_rate(1.85e8), "1.9×10^8");
        assert_eq!(fmt_s(0.0123), "12.3 ms");
        let t = time(Effort::Smoke, || {});
        assert!(t.iters >= 1 && t.min_s <= t.median_s);
    }
}
