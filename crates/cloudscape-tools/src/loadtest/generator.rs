//! The load generator's own process: the CPU it spends (so a report can set it beside
//! the server's) and where it runs (`--nice`, `--cpu`), so that on a shared box the
//! figure can describe the server rather than the generator.
//!
//! Through the `libc` crate: it is already in the dependency tree (the server reads its
//! own CPU time with it, and `proc_cpu_seconds` uses `sysconf`), and the three calls
//! needed (`getrusage`, `setpriority`, `sched_setaffinity` with their getters) are thin
//! syscalls that `nix`, `core_affinity` or `thread-priority` would only wrap. Linux
//! only, as the /proc readings beside it are: on Linux both the nice value and the CPU
//! mask belong to each thread, so they are set on every thread of the process (listed
//! in /proc/self/task), and the threads started afterwards (the runtime's) inherit them.

use serde::Serialize;

/// The most cores a `--cpu` list may name (the size of a `cpu_set_t`).
const MAX_CPUS: usize = libc::CPU_SETSIZE as usize;

/// CPU seconds (user + system) this process has used so far, all threads.
pub fn cpu_seconds() -> f64 {
    // SAFETY: getrusage writes into the zeroed struct it is given.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } != 0 {
        return 0.0;
    }
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

/// Where the generator asks to run: a lower CPU priority and/or a set of cores.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Placement {
    /// Nice value for every thread (0 to 19: higher is a lower priority).
    pub nice: Option<i32>,
    /// Cores every thread may run on.
    pub cpus: Option<Vec<usize>>,
}

/// Where the generator's threads ran, read back from the kernel at the end of a run.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct PlacementReadBack {
    /// What was asked (`--nice`, `--cpu`), in words: `as is`, `nice 19`, `cores 1`, ….
    pub mode: String,
    /// The lowest nice value of any of its threads (the highest priority any had).
    pub nice: i32,
    /// The cores any of its threads may run on.
    pub cpus: Vec<usize>,
    /// Threads read.
    pub threads: usize,
}

impl Placement {
    /// Checks `--nice`: 0 to 19 (an unprivileged process may only lower its priority).
    pub fn check_nice(n: i32) -> Result<i32, String> {
        if (0..=19).contains(&n) {
            Ok(n)
        } else {
            Err(format!(
                "--nice must be between 0 and 19 (higher runs the generator at a lower priority), got {n}"
            ))
        }
    }

    /// Parses a `--cpu` list: cores and ranges, `1`, `0,2`, `0-3,6`; each must be one
    /// this process may run on now.
    pub fn parse_cpus(s: &str) -> Result<Vec<usize>, String> {
        let bad = || format!("--cpu must list cores like 1, 0,2 or 0-3, got `{s}`");
        let mut cpus = Vec::new();
        for part in s.split(',') {
            let part = part.trim();
            let (a, b) = match part.split_once('-') {
                Some((a, b)) => (a.trim(), b.trim()),
                None => (part, part),
            };
            let (a, b): (usize, usize) = (a.parse().map_err(|_| bad())?, b.parse().map_err(|_| bad())?);
            if a > b || b >= MAX_CPUS {
                return Err(bad());
            }
            cpus.extend(a..=b);
        }
        cpus.sort_unstable();
        cpus.dedup();
        let allowed = affinity(0).map_err(|e| format!("cannot read which cores this process may use: {e}"))?;
        if let Some(c) = cpus.iter().find(|c| !allowed.contains(c)) {
            return Err(format!(
                "--cpu {s}: core {c} is not one this process may run on (it may use {})",
                cpu_list(&allowed)
            ));
        }
        Ok(cpus)
    }

    /// Whether anything is asked.
    pub fn is_default(&self) -> bool {
        self.nice.is_none() && self.cpus.is_none()
    }

    /// The mode in words, for the reports.
    pub fn mode(&self) -> String {
        let mut parts = Vec::new();
        if let Some(n) = self.nice {
            parts.push(format!("nice {n}"));
        }
        if let Some(c) = &self.cpus {
            parts.push(format!(
                "{} {}",
                if c.len() == 1 { "core" } else { "cores" },
                cpu_list(c)
            ));
        }
        if parts.is_empty() {
            "as is".into()
        } else {
            parts.join(", ")
        }
    }

    /// Applies the placement to every thread of this process; threads started later
    /// inherit it from the thread that starts them.
    pub fn apply(&self) -> Result<(), String> {
        if self.is_default() {
            return Ok(());
        }
        for tid in threads()? {
            if let Some(n) = self.nice {
                set_nice(tid, n).map_err(|e| format!("cannot lower the generator's priority to nice {n}: {e}"))?;
            }
            if let Some(cpus) = &self.cpus {
                set_affinity(tid, cpus)
                    .map_err(|e| format!("cannot pin the generator to cores {}: {e}", cpu_list(cpus)))?;
            }
        }
        Ok(())
    }

    /// Reads every thread's nice value and cores back.
    pub fn read_back(&self) -> PlacementReadBack {
        let (mut nice, mut cpus, mut n) = (i32::MAX, Vec::new(), 0);
        for tid in threads().unwrap_or_default() {
            // A thread may end between the listing and the reading.
            if let (Ok(v), Ok(c)) = (get_nice(tid), affinity(tid)) {
                nice = nice.min(v);
                cpus.extend(c);
                n += 1;
            }
        }
        cpus.sort_unstable();
        cpus.dedup();
        PlacementReadBack {
            mode: self.mode(),
            nice: if n == 0 { 0 } else { nice },
            cpus,
            threads: n,
        }
    }
}

/// `0-3,6` for `[0, 1, 2, 3, 6]`.
pub fn cpu_list(cpus: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < cpus.len() {
        let mut j = i;
        while j + 1 < cpus.len() && cpus[j + 1] == cpus[j] + 1 {
            j += 1;
        }
        out.push(if j == i {
            cpus[i].to_string()
        } else {
            format!("{}-{}", cpus[i], cpus[j])
        });
        i = j + 1;
    }
    out.join(",")
}

/// The thread ids of this process.
fn threads() -> Result<Vec<libc::pid_t>, String> {
    let dir = std::fs::read_dir("/proc/self/task").map_err(|e| format!("cannot list /proc/self/task: {e}"))?;
    Ok(dir.filter_map(|e| e.ok()?.file_name().to_str()?.parse().ok()).collect())
}

fn last_error() -> std::io::Error {
    std::io::Error::last_os_error()
}

/// Sets the nice value of thread `tid` (0: the calling thread).
fn set_nice(tid: libc::pid_t, n: i32) -> Result<(), std::io::Error> {
    // SAFETY: setpriority takes plain integers.
    if unsafe { libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, n) } == 0 {
        Ok(())
    } else {
        match last_error() {
            e if e.raw_os_error() == Some(libc::ESRCH) => Ok(()),
            e => Err(e),
        }
    }
}

/// The nice value of thread `tid` (0: the calling thread).
fn get_nice(tid: libc::pid_t) -> Result<i32, std::io::Error> {
    // getpriority may return -1 as a value: errno tells an error apart.
    // SAFETY: errno is thread-local; getpriority takes plain integers.
    unsafe {
        *libc::__errno_location() = 0;
        let v = libc::getpriority(libc::PRIO_PROCESS, tid as libc::id_t);
        if v == -1 && *libc::__errno_location() != 0 {
            return Err(last_error());
        }
        Ok(v)
    }
}

/// Pins thread `tid` (0: the calling thread) to `cpus`.
fn set_affinity(tid: libc::pid_t, cpus: &[usize]) -> Result<(), std::io::Error> {
    // SAFETY: the set is zeroed, then filled with indices below CPU_SETSIZE.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for &c in cpus {
            libc::CPU_SET(c, &mut set);
        }
        if libc::sched_setaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0 {
            return Ok(());
        }
    }
    match last_error() {
        e if e.raw_os_error() == Some(libc::ESRCH) => Ok(()),
        e => Err(e),
    }
}

/// The cores thread `tid` (0: the calling thread) may run on.
fn affinity(tid: libc::pid_t) -> Result<Vec<usize>, std::io::Error> {
    // SAFETY: sched_getaffinity fills the zeroed set; CPU_ISSET reads it.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
            return Err(last_error());
        }
        Ok((0..MAX_CPUS).filter(|&c| libc::CPU_ISSET(c, &set)).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_counts_its_cpu_time() {
        let before = cpu_seconds();
        // Spin until the clock moves (getrusage has microsecond fields, but a tick granularity).
        let mut x = 0u64;
        while cpu_seconds() <= before {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
        }
        std::hint::black_box(x);
        assert!(cpu_seconds() > before);
    }

    #[test]
    fn cpu_lists_parse_and_bad_ones_are_one_sentence() {
        let allowed = affinity(0).unwrap();
        let first = allowed[0];
        assert_eq!(Placement::parse_cpus(&first.to_string()).unwrap(), vec![first]);
        if allowed.len() >= 2 {
            let s = format!("{},{}", allowed[1], allowed[0]);
            assert_eq!(Placement::parse_cpus(&s).unwrap(), vec![allowed[0], allowed[1]]);
        }
        for bad in ["", "x", "1-", "3-1", "-1", "1,,2", "4096", "0.5"] {
            let e = Placement::parse_cpus(bad).unwrap_err();
            assert!(
                e.starts_with("--cpu must list cores") && !e.contains('\n'),
                "{bad}: {e}"
            );
        }
        let outside = (0..MAX_CPUS).find(|c| !allowed.contains(c)).unwrap();
        let e = Placement::parse_cpus(&outside.to_string()).unwrap_err();
        assert!(e.contains(&format!("core {outside} is not one")), "{e}");
        assert_eq!(cpu_list(&[0, 1, 2, 3, 6, 8, 9]), "0-3,6,8-9");
    }

    #[test]
    fn nice_values_are_checked_and_the_mode_is_named() {
        assert_eq!(Placement::check_nice(19), Ok(19));
        assert!(
            Placement::check_nice(-1)
                .unwrap_err()
                .starts_with("--nice must be between 0 and 19")
        );
        assert!(Placement::check_nice(20).is_err());
        assert_eq!(Placement::default().mode(), "as is");
        let p = Placement {
            nice: Some(10),
            cpus: Some(vec![1]),
        };
        assert_eq!(p.mode(), "nice 10, core 1");
    }

    #[test]
    fn a_thread_s_priority_and_cores_are_set_and_read_back() {
        // On a thread of its own: the test harness's other threads keep theirs.
        let allowed = affinity(0).unwrap();
        let core = *allowed.last().unwrap();
        let (nice, cores) = std::thread::spawn(move || {
            set_nice(0, 15).unwrap();
            set_affinity(0, &[core]).unwrap();
            (get_nice(0).unwrap(), affinity(0).unwrap())
        })
        .join()
        .unwrap();
        assert_eq!((nice, cores), (15, vec![core]));
        // This thread is untouched.
        assert_eq!(affinity(0).unwrap(), allowed);
    }
}
