//! `--out` through the binary (issue 25, part 5): regular files replaced atomically,
//! symlinks followed and kept, FIFOs and devices written in place, `-` for stdout,
//! `/dev/full` a clean error, and no stray temporary files after a kill -9.

mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use common::assert_success;

const BIN: &str = env!("CARGO_BIN_EXE_cloudscape");

/// A small grid: 3 km × 2 km of the default world's first layer.
const ARGS: [&str; 8] = [
    "--world",
    "default",
    "--bbox",
    "0,0,3000,2000",
    "--t",
    "120",
    "--format",
    "npy",
];

fn density(out: &str) -> Output {
    Command::new(BIN)
        .arg("density")
        .args(ARGS)
        .args(["--out", out])
        .output()
        .expect("run cloudscape density")
}

/// The bytes `density` writes to a fresh regular file (the reference for the rest).
fn reference(dir: &Path) -> Vec<u8> {
    let p = dir.join("reference.npy");
    assert_success(&density(p.to_str().unwrap()));
    let bytes = std::fs::read(&p).unwrap();
    assert!(bytes.starts_with(b"\x93NUMPY"), "an .npy file");
    bytes
}

fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    names
}

#[test]
fn symlink_stays_a_link_and_its_target_gets_the_bytes() {
    let d = tempfile::tempdir().unwrap();
    let want = reference(d.path());
    let target = d.path().join("target.npy");
    std::fs::write(&target, b"old").unwrap();
    let link = d.path().join("link.npy");
    std::os::unix::fs::symlink("target.npy", &link).unwrap();
    assert_success(&density(link.to_str().unwrap()));
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
    assert_eq!(std::fs::read_link(&link).unwrap(), Path::new("target.npy"));
    assert_eq!(std::fs::read(&target).unwrap(), want);
    assert_eq!(entries(d.path()), ["link.npy", "reference.npy", "target.npy"]);
}

#[test]
fn fifo_is_written_in_place_for_its_reader() {
    let d = tempfile::tempdir().unwrap();
    let want = reference(d.path());
    let fifo = d.path().join("pipe.npy");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read(fifo).unwrap())
    };
    assert_success(&density(fifo.to_str().unwrap()));
    assert_eq!(reader.join().unwrap(), want);
    let kind = std::fs::symlink_metadata(&fifo).unwrap().file_type();
    use std::os::unix::fs::FileTypeExt;
    assert!(kind.is_fifo(), "the FIFO is still a FIFO");
    assert_eq!(entries(d.path()), ["pipe.npy", "reference.npy"]);
}

#[test]
fn dev_null_works_and_dev_full_is_a_clean_error() {
    assert_success(&density("/dev/null"));
    let o = density("/dev/full");
    assert!(!o.status.success(), "writing to /dev/full must fail");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.starts_with("error: cannot write /dev/full"), "{err}");
    assert!(err.to_lowercase().contains("no space"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    // /dev/full is still the device.
    use std::os::unix::fs::FileTypeExt;
    assert!(std::fs::metadata("/dev/full").unwrap().file_type().is_char_device());
}

#[test]
fn dash_writes_the_npy_to_stdout() {
    let d = tempfile::tempdir().unwrap();
    let want = reference(d.path());
    let o = density("-");
    assert_success(&o);
    assert_eq!(o.stdout, want, "stdout carries exactly the .npy bytes");
    // Redirected to a file, as a shell would: the file is a whole .npy.
    let f = std::fs::File::create(d.path().join("redirected.npy")).unwrap();
    let status = Command::new(BIN)
        .arg("density")
        .args(ARGS)
        .args(["--out", "-"])
        .stdout(f)
        .status()
        .unwrap();
    assert!(status.success());
    assert_eq!(std::fs::read(d.path().join("redirected.npy")).unwrap(), want);
}

#[test]
fn no_stray_temporaries_after_kill_9() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("grid.npy");
    // A temporary file left by a process that died: a real, finished process's pid.
    let mut gone = Command::new("true").spawn().unwrap();
    let pid = gone.id();
    gone.wait().unwrap();
    let stale = d.path().join(format!(".grid.npy.cloudscape-tmp-{pid}-0"));
    std::fs::write(&stale, vec![0u8; 4096]).unwrap();
    // A large grid, killed while it runs (computing or writing: either must be safe).
    for delay_ms in [300, 700, 1000, 1200] {
        let mut child = Command::new(BIN)
            .arg("density")
            .args(["--world", "default", "--bbox", "0,0,80000,80000", "--t", "120"])
            .args(["--out", out.to_str().unwrap()])
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(delay_ms));
        let _ = child.kill(); // SIGKILL
        let _ = child.wait();
    }
    assert_success(&density(out.to_str().unwrap()));
    assert_eq!(entries(d.path()), ["grid.npy"], "only the product is left");
    assert!(std::fs::read(&out).unwrap().starts_with(b"\x93NUMPY"));
}
