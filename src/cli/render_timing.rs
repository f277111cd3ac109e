//! Timing statistics of `spinedrr render --repeat N` (mesh and CT renders alike).

/// The median and the minimum of `times` (sorted in place; not empty).
pub fn median_min(times: &mut [f64]) -> (f64, f64) {
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], times[0])
}

/// Peak resident memory of this process so far (MiB), from /proc/self/status (Linux; null elsewhere).
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}
