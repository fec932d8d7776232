//! Resident memory, for the check that it stays flat.

/// Resident memory from a `/proc/<pid>/statm` file, in KiB (0 if unreadable).
pub(super) fn rss_kib(statm: &str) -> u64 {
    std::fs::read_to_string(statm)
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |pages| pages * 4)
}
