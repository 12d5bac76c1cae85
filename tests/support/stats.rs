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
