//! CI smoke of `cloudscape bench` and `cloudscape loadtest` through the built binary:
//! they run, write what they say, and report sane figures. No timing thresholds.

mod common;

use std::process::Command;

use common::{ServeProcess, assert_success, cloudscape};

/// Decodes a PNG and returns its size.
fn png_size(path: &std::path::Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap_or_else(|e| panic!("{} is not a PNG: {e}", path.display()));
    (reader.info().width, reader.info().height)
}

fn f(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut v = v;
    for p in path {
        v = &v[p];
    }
    v.as_f64().unwrap_or_else(|| panic!("{path:?} is not a number: {v}"))
}

/// Runs `cloudscape bench --smoke` into `md` (plots beside it) and calls `edit`
/// once the run has read `md` and started measuring (its first progress line).
/// Returns the exit status, the run's stderr and whether it was still running
/// right after the edit (if not, the edit tested nothing).
fn bench_smoke_editing_midway(md: &std::path::Path, edit: impl FnOnce()) -> (std::process::ExitStatus, String, bool) {
    use std::io::BufRead;
    let plots = md.parent().unwrap().join("plots");
    let mut child = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["bench", "--smoke", "--out", md.to_str().unwrap()])
        .args(["--plots", plots.to_str().unwrap()])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run cloudscape");
    let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    while !seen.contains("bench: machine") {
        if stderr.read_line(&mut seen).unwrap() == 0 {
            panic!("no progress line; exit {:?}, stderr: {seen}", child.wait());
        }
    }
    edit();
    let running_at_edit = child.try_wait().unwrap().is_none();
    seen.push_str(&std::io::read_to_string(stderr).unwrap());
    (child.wait().unwrap(), seen, running_at_edit)
}

#[test]
fn bench_smoke_writes_every_section_between_markers_and_keeps_prose() {
    let dir = tempfile::tempdir().unwrap();
    let md = dir.path().join("BENCHMARKS.md");
    // Prose may quote a marker (BENCHMARKS.md's heading does): it is not one.
    let prose = "# Benchmarks\n\nHand-written prose about `<!-- bench:ID:begin/end -->` markers.\n\n\
                 <!-- bench:http:begin -->\nstale\n<!-- bench:http:end -->\n\nAfter the markers.\n";
    std::fs::write(&md, prose).unwrap();
    // A paragraph written while the bench measures must survive its write at the
    // end (it was lost when the file was read only at the start).
    let edit = "\nA paragraph written while the bench measured.\n";
    let (status, stderr, running_at_edit) = bench_smoke_editing_midway(&md, || {
        use std::io::Write;
        let mut f = std::fs::OpenOptions::new().append(true).open(&md).unwrap();
        f.write_all(edit.as_bytes()).unwrap();
    });
    assert!(status.success(), "exit {status:?}: {stderr}");
    let text = std::fs::read_to_string(&md).unwrap();
    assert!(text.starts_with(
        "# Benchmarks\n\nHand-written prose about `<!-- bench:ID:begin/end -->` markers.\n\n<!-- bench:http:begin -->\n"
    ));
    assert!(text.contains("<!-- bench:http:end -->\n\nAfter the markers.\n"));
    assert!(!text.contains("stale"));
    assert!(
        running_at_edit,
        "the smoke run ended before the edit; nothing was tested"
    );
    assert!(text.contains(edit), "the edit made during the run was kept");
    let plots = dir.path().join("plots");
    for id in cloudscape_tools::bench::SECTION_NAMES {
        let (b, e) = (format!("<!-- bench:{id}:begin -->"), format!("<!-- bench:{id}:end -->"));
        let (i, j) = (text.find(&b), text.find(&e));
        assert!(matches!((i, j), (Some(i), Some(j)) if i < j), "section {id} missing");
        let body = &text[i.unwrap() + b.len()..j.unwrap()];
        assert!(body.contains("| "), "section {id} has no table: {body}");
        assert_eq!(text.matches(&b).count(), 1, "section {id} written twice");
    }
    assert!(text.contains("| cores | "));
    assert!(text.contains("| 10 × 100 × 10 | 10000 | 0.28 |"), "Rosa's first row");
    for plot in ["scaling.png", "rosa.png", "quality.png"] {
        let (w, h) = png_size(&plots.join(plot));
        assert!(w >= 200 && h >= 200, "{plot}: {w}×{h}");
        assert!(text.contains(&format!("](plots/{plot})")), "{plot} is linked");
    }
}

#[test]
fn bench_only_rewrites_the_sections_it_names() {
    let dir = tempfile::tempdir().unwrap();
    let md = dir.path().join("BENCHMARKS.md");
    let doc = "# Benchmarks\n\n<!-- bench:http:begin -->\nkept\n<!-- bench:http:end -->\n\n\
               <!-- bench:quality:begin -->\nstale\n<!-- bench:quality:end -->\n";
    std::fs::write(&md, doc).unwrap();
    let plots = dir.path().join("plots");
    let out = cloudscape(&[
        "bench",
        "--smoke",
        "--only",
        "quality",
        "--out",
        md.to_str().unwrap(),
        "--plots",
        plots.to_str().unwrap(),
    ]);
    assert_success(&out);
    let text = std::fs::read_to_string(&md).unwrap();
    assert!(
        text.contains("<!-- bench:http:begin -->\nkept\n<!-- bench:http:end -->"),
        "{text}"
    );
    assert!(!text.contains("stale") && text.contains("split half"), "{text}");
    assert!(
        !text.contains("bench:machine:begin"),
        "only the named section is measured"
    );
    // An unknown section is refused before any measuring, naming the known ones.
    let bad = cloudscape(&[
        "bench",
        "--smoke",
        "--only",
        "quality,nope",
        "--out",
        md.to_str().unwrap(),
    ]);
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("`nope`") && err.contains("scaling"), "{err}");
    assert_eq!(
        std::fs::read_to_string(&md).unwrap(),
        text,
        "a refused run writes nothing"
    );
}

#[test]
fn bench_keeps_its_figures_when_an_edit_midway_breaks_the_markers() {
    let dir = tempfile::tempdir().unwrap();
    let md = dir.path().join("BENCHMARKS.md");
    std::fs::write(&md, "# Benchmarks\n").unwrap();
    let broken = "# Benchmarks\n<!-- bench:automaton:begin -->\n";
    let (status, stderr, running_at_edit) = bench_smoke_editing_midway(&md, || std::fs::write(&md, broken).unwrap());
    assert!(
        running_at_edit,
        "the smoke run ended before the edit; nothing was tested"
    );
    assert!(!status.success(), "broken markers must fail the run: {stderr}");
    let side = dir.path().join("BENCHMARKS.md.sections.md");
    assert!(
        stderr.contains("are broken") && stderr.contains("BENCHMARKS.md.sections.md"),
        "{stderr}"
    );
    // The edited file is left as the editor left it; the figures are not lost.
    assert_eq!(std::fs::read_to_string(&md).unwrap(), broken);
    let sections = std::fs::read_to_string(&side).unwrap();
    for id in ["machine", "automaton", "scaling"] {
        assert!(
            sections.contains(&format!("<!-- bench:{id}:begin -->\n")),
            "section {id} in {side:?}"
        );
    }
}

#[test]
fn loadtest_reports_sane_figures_against_a_live_server() {
    let server = ServeProcess::start(&[], &[("RUST_LOG", "warn")]);
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("report.json");
    let plot = dir.path().join("latency.png");

    // Closed loop, players and game servers, a frozen clock (so views revalidate).
    let out = cloudscape(&[
        "loadtest",
        "--target",
        &server.base,
        "--players",
        "8",
        "--duration",
        "4s",
        "--scenario",
        "mixed",
        "--clock",
        "0",
        "--json",
        json.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert_success(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("latency ms: p50"), "{stdout}");
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(r["mode"], "closed");
    assert_eq!((r["players"].as_u64(), r["game_servers"].as_u64()), (Some(8), Some(1)));
    let requests = f(&r, &["totals", "requests"]);
    assert!(requests > 0.0, "{r}");
    let counted: f64 = ["ok", "not_modified", "shed", "other_status", "transport_errors"]
        .iter()
        .map(|k| f(&r, &["totals", k]))
        .sum();
    assert_eq!(counted, requests);
    assert_eq!(f(&r, &["totals", "transport_errors"]), 0.0, "{r}");
    let lat: Vec<f64> = ["min_ms", "p50_ms", "p90_ms", "p99_ms", "max_ms"]
        .iter()
        .map(|k| f(&r, &["latency", k]))
        .collect();
    assert!(lat[0] > 0.0 && lat.windows(2).all(|w| w[0] <= w[1]), "{lat:?}");
    assert!(f(&r, &["throughput_rps"]) > 0.0);
    assert!(
        r["by_kind"]["tile"]["requests"].as_u64().unwrap() > 0,
        "players fetched tiles: {r}"
    );
    // The generator's own CPU, beside the server's.
    assert!(f(&r, &["generator", "cpu_seconds"]) > 0.0, "{}", r["generator"]);
    assert!(f(&r, &["generator", "cpu_cores"]) > 0.0);
    assert_eq!(r["generator"]["placement"]["mode"], "as is");
    assert!(stdout.contains("CPU, share of one core: server "), "{stdout}");
    // The generator's own scheduling delay, from its 10 ms probe timer: measured (a
    // timer never wakes early, so every sample is > 0) and ordered.
    let lag: Vec<f64> = ["min_ms", "p50_ms", "p99_ms", "max_ms"]
        .iter()
        .map(|k| f(&r, &["generator", "lag", k]))
        .collect();
    assert!(lag[0] > 0.0 && lag.windows(2).all(|w| w[0] <= w[1]), "{lag:?}");
    assert!(
        stdout.contains("generator lag (its own 10 ms timer, late by) p99 "),
        "{stdout}"
    );
    // The default geometry: one group of 8 in a town, one distinct place.
    assert_eq!(r["geometry"]["kind"], "towns");
    assert_eq!(r["geometry"]["groups"], 1);
    assert_eq!(r["distinct_places"], 1);
    // Sharing per level: one group, so no keyframe is asked by two; every level the
    // players asked for is listed once, finest first.
    let sharing = r["sharing"].as_array().unwrap();
    assert!(!sharing.is_empty(), "{r}");
    let levels: Vec<u64> = sharing.iter().map(|l| l["level"].as_u64().unwrap()).collect();
    assert!(levels.windows(2).all(|w| w[0] < w[1]), "{levels:?}");
    for l in sharing {
        assert_eq!(l["shared_by_2_groups"], 0.0, "{l}");
        assert!(f(l, &["requests"]) >= f(l, &["keyframes"]) && f(l, &["keyframes"]) > 0.0);
    }
    // Without --t the run starts at the server's clock when discovery has one.
    let d: serde_json::Value = serde_json::from_str(&server.get("/v1/worlds/default").text().unwrap()).unwrap();
    match d.get("clock") {
        Some(c) => {
            assert_eq!(r["clock_source"], "server");
            let now = f(c, &["now"]);
            assert!((f(&r, &["t0"]) - now).abs() < 120.0, "t0 {} against now {now}", r["t0"]);
        }
        None => {
            assert_eq!(r["clock_source"], "default");
            assert_eq!(f(&r, &["t0"]), 43_200.0);
        }
    }
    // The server's cache counters moved: every answered request looked the cache up or revalidated.
    let hits = f(&r, &["cache", "hits"]);
    let misses = f(&r, &["cache", "misses"]);
    assert!(hits + misses > 0.0, "{r}");
    let (w, h) = png_size(&plot);
    assert!(w > 400 && h > 200);

    // Open loop at a fixed rate: latency from the intended send time.
    let out = cloudscape(&[
        "loadtest",
        "--target",
        &server.base,
        "--players",
        "2",
        "--duration",
        "2s",
        "--scenario",
        "queries",
        "--rate",
        "10",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert_success(&out);
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(r["mode"], "open");
    let requests = f(&r, &["totals", "requests"]);
    assert!((10.0..=21.0).contains(&requests), "about rate × duration requests: {r}");
    assert!(r["by_kind"]["region"]["requests"].as_u64().unwrap() > 0);
    assert!(f(&r, &["latency", "p50_ms"]) <= f(&r, &["latency", "max_ms"]));
}

/// A core this process may run on (the last of them).
fn an_allowed_core() -> usize {
    // SAFETY: sched_getaffinity fills the zeroed set; CPU_ISSET reads it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        assert_eq!(
            libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set),
            0
        );
        (0..libc::CPU_SETSIZE as usize)
            .rev()
            .find(|&c| libc::CPU_ISSET(c, &set))
            .unwrap()
    }
}

#[test]
fn a_niced_and_pinned_sweep_reports_where_the_generator_ran() {
    let server = ServeProcess::start(&[], &[("RUST_LOG", "warn")]);
    let dir = tempfile::tempdir().unwrap();
    let (json, md, plot) = (
        dir.path().join("sweep.json"),
        dir.path().join("B.md"),
        dir.path().join("c.png"),
    );
    std::fs::write(&md, "# Benchmarks\n").unwrap();
    let core = an_allowed_core().to_string();
    let out = cloudscape(&[
        "loadtest",
        "--target",
        &server.base,
        "--sweep",
        "--steps",
        "8",
        "--duration",
        "2s",
        "--geometry",
        "spread",
        "--nice",
        "7",
        "--cpu",
        &core,
        "--json",
        json.to_str().unwrap(),
        "--markdown",
        md.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert_success(&out);
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    // Read back from the kernel, every thread of the generator.
    let p = &r["placement"];
    assert_eq!(p["mode"], format!("nice 7, core {core}"), "{r}");
    assert_eq!(p["nice"], 7);
    assert_eq!(p["cpus"], serde_json::json!([core.parse::<u64>().unwrap()]));
    assert!(
        p["threads"].as_u64().unwrap() >= 3,
        "the runtime's threads were read: {p}"
    );
    let step = &r["steps"][0];
    assert_eq!(step["players"], 8);
    assert!(f(step, &["generator_cpu_cores"]) > 0.0, "{step}");
    assert!(f(step, &["generator_lag_p99_ms"]) > 0.0, "{step}");
    // One group on its own path: one place, nothing shared between groups.
    assert_eq!((step["groups"].as_u64(), step["places"].as_u64()), (Some(1), Some(1)));
    assert_eq!(r["geometry"]["kind"], "spread");
    assert!(!step["sharing"].as_array().unwrap().is_empty(), "{step}");
    let text = std::fs::read_to_string(&md).unwrap();
    assert!(text.contains("<!-- bench:capacity:begin -->"), "{text}");
    assert!(text.contains("| players | places | requests/s |") && text.contains("| generator CPU |"));
    assert!(
        text.contains(&format!(
            "Generator: nice 7, core {core} (read back: nice 7, cores {core})"
        )),
        "{text}"
    );
    assert!(text.contains("| players | level | keyframes |"), "{text}");
    let (w, h) = png_size(&plot);
    assert!(w >= 1000 && h > 200, "three panels: {w}×{h}");
}

#[test]
fn bad_input_is_one_error_line_and_a_failure() {
    for args in [
        &["loadtest", "--target", "http://127.0.0.1:1", "--scenario", "raid"][..],
        &["loadtest", "--target", "http://127.0.0.1:1", "--geometry", "grid"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--nice", "25"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--nice", "-3"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--nice", "low"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--cpu", "99999"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--cpu", "a-b"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--cpu", "1023"],
        &["loadtest", "--target", "127.0.0.1:1"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--duration", "forever"],
        &["loadtest", "--target", "http://127.0.0.1:1", "--rate", "-3"],
        // Nothing listens there: discovery fails with the URL named.
        &["loadtest", "--target", "http://127.0.0.1:1", "--duration", "1s"],
    ] {
        let out = cloudscape(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(
            stderr.starts_with("error: ") && stderr.trim_end().lines().count() == 1,
            "{args:?}: {stderr}"
        );
    }
    // Broken markers are refused before any measuring.
    let dir = tempfile::tempdir().unwrap();
    let md = dir.path().join("B.md");
    std::fs::write(&md, "<!-- bench:rosa:end -->\n<!-- bench:rosa:begin -->\n").unwrap();
    let out = cloudscape(&["bench", "--smoke", "--out", md.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("markers of section `rosa`"));
}
