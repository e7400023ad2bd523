//! What this machine can give the server: its memory, which the config's byte budgets
//! are held to at start ([`crate::check_config`]).

/// The memory this process may use, bytes, and where that figure comes from: the
/// cgroup's limit (a container's `memory.max`) when there is one and it is lower, else
/// the machine's `MemTotal`. `None` where neither can be read (not Linux).
pub fn memory() -> Option<(u64, &'static str)> {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| mem_total(&m))
        .map(|b| (b, "the machine's memory (MemTotal)"));
    let cgroup = [
        "/sys/fs/cgroup/memory.max",
        "/sys/fs/cgroup/memory/memory.limit_in_bytes",
    ]
    .iter()
    .find_map(|p| std::fs::read_to_string(p).ok())
    .and_then(|v| v.trim().parse::<u64>().ok())
    .map(|b| (b, "the container's memory limit (cgroup)"));
    match (total, cgroup) {
        (Some(t), Some(c)) => Some(if c.0 < t.0 { c } else { t }),
        (t, c) => t.or(c),
    }
}

/// `MemTotal` of `/proc/meminfo`, bytes.
fn mem_total(meminfo: &str) -> Option<u64> {
    let kb = meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:"))?
        .trim()
        .strip_suffix("kB")?
        .trim()
        .parse::<u64>()
        .ok()?;
    kb.checked_mul(1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mem_total_is_read_in_bytes() {
        assert_eq!(
            mem_total("MemFree: 1 kB\nMemTotal:       24683772 kB\n"),
            Some(24_683_772 * 1024)
        );
        assert_eq!(mem_total("MemTotal: lots\n"), None);
        if cfg!(target_os = "linux") {
            let (bytes, _) = memory().expect("Linux says");
            assert!(bytes > 1 << 20);
        }
    }
}
