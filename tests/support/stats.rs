//! Figures for the benchmarks and the tests that measure: one rule for
//! percentiles, so every figure printed means the same thing.

use std::cmp::Ordering;

/// The `p`-quantile (`0.0..=1.0`) of `samples`, nearest rank on the sorted
/// values (`p = 0.5` is the median, `1.0` the maximum). Panics on no
/// samples: a benchmark that measured nothing must say so.
pub fn percentile<T: Copy + PartialOrd>(samples: &[T], p: f64) -> T {
    assert!(!samples.is_empty(), "no samples to take a percentile of");
    let mut v = samples.to_vec();
    v.sort_by(|a, b| a.partial_cmp(b).unwrap_or(Ordering::Equal));
    let i = ((v.len() as f64 - 1.0) * p.clamp(0.0, 1.0)).round() as usize;
    v[i.min(v.len() - 1)]
}

/// The median of `samples`.
pub fn median<T: Copy + PartialOrd>(samples: &[T]) -> T {
    percentile(samples, 0.5)
}

/// The tail figure with its honest name: the 99th percentile when there
/// are at least 100 samples, else the maximum (a "p99" of 20 samples is
/// the maximum), as `("p99" | "max", value)`.
pub fn tail<T: Copy + PartialOrd>(samples: &[T]) -> (&'static str, T) {
    if samples.len() >= 100 {
        ("p99", percentile(samples, 0.99))
    } else {
        ("max", percentile(samples, 1.0))
    }
}

/// A process's CPU time so far, utime + stime, in clock ticks.
pub fn cpu_ticks(pid: u32) -> u64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let rest = stat.rsplit_once(')').map(|x| x.1).unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let n = |i: usize| f.get(i).and_then(|x| x.parse::<u64>().ok()).unwrap_or(0);
    n(11) + n(12)
}

/// A process's resident memory, MiB.
pub fn rss_mib(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|k| k.parse::<f64>().ok())
        .map_or(0.0, |k| k / 1024.0)
}
