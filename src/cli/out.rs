//! Where every `--out` goes: what a user expects of `> FILE`, without partial files.
//!
//! - A regular file, or a path that does not exist yet, is replaced atomically: the
//!   bytes go to a temporary file in the same directory, are synced, and the temporary
//!   file is renamed over the target. Readers see the old bytes or the new, never half.
//!   An existing file keeps its permissions; a new one gets 0666 less the umask.
//! - A symlink is followed (through chains, also to a target that does not exist yet):
//!   its final target gets the bytes as above, and the link stays a link.
//! - Anything else — a FIFO, a character device (`/dev/null`, `/dev/full`, a tty),
//!   `-` for standard output — is written in place, as a stream; a failed write
//!   (`/dev/full`: no space) is an error and the command exits non-zero.
//!
//! Temporary files are named `.<name>.cloudscape-tmp-<pid>-<n>` beside the target.
//! A process killed mid-write (kill -9) leaves one behind; the next write to the same
//! target removes those whose process is gone. (Named files rather than `O_TMPFILE` +
//! `linkat`: that needs `/proc` or `CAP_DAC_READ_SEARCH` to link, is Linux-only and
//! not on every filesystem; a named file works everywhere and the name says whose it is.)

use std::fs::{self, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Symlink hops followed before giving up (as Linux's `ELOOP`).
const MAX_HOPS: usize = 40;

/// Writes `bytes` to `path` as the module doc says.
pub(crate) fn write_out(path: &str, bytes: &[u8]) -> Result<(), String> {
    if path == "-" {
        let mut out = io::stdout().lock();
        return out
            .write_all(bytes)
            .and_then(|()| out.flush())
            .map_err(|e| format!("cannot write to standard output: {e}"));
    }
    let fail = |e: io::Error| format!("cannot write {path}: {e}");
    let target = resolve(Path::new(path)).map_err(fail)?;
    match fs::metadata(&target) {
        Ok(m) if m.is_file() => replace(&target, bytes, Some(m.permissions())).map_err(fail),
        Ok(m) if m.is_dir() => Err(format!("cannot write {path}: it is a directory")),
        Ok(_) => {
            // FIFO, device, socket: write in place; never truncate or replace it.
            let mut f = OpenOptions::new().write(true).open(&target).map_err(fail)?;
            f.write_all(bytes).and_then(|()| f.flush()).map_err(fail)
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => replace(&target, bytes, None).map_err(fail),
        Err(e) => Err(fail(e)),
    }
}

/// The path a write to `path` lands on: `path` itself unless it is a symlink, else the
/// final target of the chain (which may not exist yet).
fn resolve(path: &Path) -> io::Result<PathBuf> {
    let mut p = path.to_path_buf();
    for _ in 0..MAX_HOPS {
        match fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let link = fs::read_link(&p)?;
                p = match p.parent() {
                    Some(dir) if link.is_relative() => dir.join(link),
                    _ => link,
                };
            }
            _ => return Ok(p),
        }
    }
    Err(io::Error::other("too many levels of symbolic links"))
}

/// Distinguishes the temporary files of one process.
static SERIAL: AtomicU64 = AtomicU64::new(0);

/// The directory and file name of `target`.
fn split(target: &Path) -> io::Result<(PathBuf, String)> {
    let name = target
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "the path has no file name"))?;
    let dir = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    Ok((dir, name.to_string()))
}

fn temp_prefix(name: &str) -> String {
    format!(".{name}.cloudscape-tmp-")
}

/// Replaces the regular file (or creates the file) `target` atomically.
fn replace(target: &Path, bytes: &[u8], permissions: Option<fs::Permissions>) -> io::Result<()> {
    let (dir, name) = split(target)?;
    remove_stale_temps(&dir, &name);
    let tmp = dir.join(format!(
        "{}{}-{}",
        temp_prefix(&name),
        std::process::id(),
        SERIAL.fetch_add(1, Ordering::Relaxed)
    ));
    let written = (|| {
        let mut f = OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        if let Some(p) = permissions {
            f.set_permissions(p)?;
        }
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        fs::rename(&tmp, target)
    })();
    if written.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    written
}

/// Removes temporary files for `name` in `dir` left by processes that no longer run.
fn remove_stale_temps(dir: &Path, name: &str) {
    let prefix = temp_prefix(name);
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let file = entry.file_name();
        let Some(rest) = file.to_str().and_then(|f| f.strip_prefix(&prefix)) else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if pid != std::process::id() && !process_alive(pid) {
            let _ = fs::remove_file(entry.path());
        }
    }
}

/// Whether a process `pid` exists (a recycled pid counts as alive: its file stays).
fn process_alive(pid: u32) -> bool {
    #[cfg(unix)]
    {
        let Ok(pid) = libc::pid_t::try_from(pid) else {
            return false;
        };
        // SAFETY: signal 0 only checks that the process exists and may be signalled.
        let r = unsafe { libc::kill(pid, 0) };
        r == 0 || io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        true
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    #[test]
    fn replaces_files_and_follows_symlink_chains() {
        let d = tempfile::tempdir().unwrap();
        let real = d.path().join("real.bin");
        fs::write(&real, b"old").unwrap();
        let a = d.path().join("a");
        let b = d.path().join("b");
        std::os::unix::fs::symlink("real.bin", &a).unwrap();
        std::os::unix::fs::symlink(&a, &b).unwrap();
        write_out(b.to_str().unwrap(), b"new bytes").unwrap();
        assert_eq!(fs::read(&real).unwrap(), b"new bytes");
        assert!(fs::symlink_metadata(&a).unwrap().file_type().is_symlink());
        assert!(fs::symlink_metadata(&b).unwrap().file_type().is_symlink());
        // A dangling link gets its target created.
        let dangling = d.path().join("dangling");
        std::os::unix::fs::symlink("later.bin", &dangling).unwrap();
        write_out(dangling.to_str().unwrap(), b"x").unwrap();
        assert_eq!(fs::read(d.path().join("later.bin")).unwrap(), b"x");
        assert!(fs::symlink_metadata(&dangling).unwrap().file_type().is_symlink());
        // A loop is an error, not a hang.
        let l1 = d.path().join("l1");
        let l2 = d.path().join("l2");
        std::os::unix::fs::symlink("l2", &l1).unwrap();
        std::os::unix::fs::symlink("l1", &l2).unwrap();
        let e = write_out(l1.to_str().unwrap(), b"x").unwrap_err();
        assert!(e.contains("symbolic links"), "{e}");
        // Only the files written are left: no temporaries.
        let mut names: Vec<String> = fs::read_dir(d.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["a", "b", "dangling", "l1", "l2", "later.bin", "real.bin"]);
    }

    #[test]
    fn existing_permissions_are_kept() {
        use std::os::unix::fs::PermissionsExt;
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("f");
        fs::write(&f, b"old").unwrap();
        fs::set_permissions(&f, fs::Permissions::from_mode(0o640)).unwrap();
        write_out(f.to_str().unwrap(), b"new").unwrap();
        assert_eq!(fs::metadata(&f).unwrap().permissions().mode() & 0o777, 0o640);
    }

    #[test]
    fn stale_temps_of_dead_processes_go_live_ones_stay() {
        let d = tempfile::tempdir().unwrap();
        // pid_max on Linux is at most 2^22: this pid cannot be running.
        let dead = d.path().join(".out.npy.cloudscape-tmp-4194305-0");
        let live = d
            .path()
            .join(format!(".out.npy.cloudscape-tmp-{}-99", std::process::id()));
        let other = d.path().join(".other.npy.cloudscape-tmp-4194305-0");
        for p in [&dead, &live, &other] {
            fs::write(p, b"partial").unwrap();
        }
        write_out(d.path().join("out.npy").to_str().unwrap(), b"whole").unwrap();
        assert!(!dead.exists(), "a dead process's temporary file is removed");
        assert!(live.exists(), "a running process's temporary file stays");
        assert!(other.exists(), "another target's temporary file stays");
    }

    #[test]
    fn directories_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let e = write_out(d.path().to_str().unwrap(), b"x").unwrap_err();
        assert!(e.contains("directory"), "{e}");
    }
}
