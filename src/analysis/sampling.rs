//! The sample period of a periodically sent signal whose timestamps jitter, and its gaps.
//!
//! An ECU sends a signal at a fixed period; what a log records is the receive time, which can
//! jitter by a large part of a period (the real comma2k19 RAV4 log: steering every 12.06 ms on
//! average, intervals from 0 to 29 ms, median 11.2 ms, because the logger timestamps frames in
//! batches). The median interval is then a poor estimate of the period, and a time grid built
//! from it duplicates or drops samples. What holds instead: consecutive samples are one period
//! apart, except across a gap, and an interval only counts as a gap when it is longer than any
//! jitter makes it ([`GAP_FACTOR`] periods).
//!
//! What it is: [`fit`], one pass over the timestamps, no allocation. What it is not: a
//! resampler (the feature extractor places the samples) or a judgement of the data's quality.

/// An interval longer than this many mean periods is a gap (frames lost, or the signal timed
/// out); shorter ones are jitter.
pub const GAP_FACTOR: f64 = 2.5;

/// Period and gaps of a sequence of sample times.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    /// Sample period (ns): the span divided by the number of periods it holds.
    pub period_ns: f64,
    /// Samples missing in the gaps.
    pub missing: u32,
}

impl Fit {
    /// Grid slots a step of `dt_ns` between two consecutive samples advances: 1, or the periods
    /// a gap spans.
    pub fn slots(&self, dt_ns: i64) -> usize {
        let r = dt_ns as f64 / self.period_ns;
        if r > GAP_FACTOR {
            r.round().max(1.0) as usize
        } else {
            1
        }
    }
}

/// The period and gaps of the samples whose times `times` yields (increasing; at least two
/// distinct), or `None`.
pub fn fit<I>(times: I) -> Option<Fit>
where
    I: Iterator<Item = i64> + Clone,
{
    let mut it = times.clone();
    let first = it.next()?;
    let (mut n, mut last) = (1u64, first);
    for t in it {
        n += 1;
        last = t;
    }
    let span = (last - first) as f64;
    if n < 2 || span <= 0.0 {
        return None;
    }
    // First the mean interval, then again without the gaps it found.
    let mut period = span / (n - 1) as f64;
    let mut missing = 0u64;
    for _ in 0..2 {
        let (mut m, mut prev) = (0u64, first);
        for t in times.clone().skip(1) {
            let r = (t - prev) as f64 / period;
            if r > GAP_FACTOR {
                m += (r.round() as u64).saturating_sub(1);
            }
            prev = t;
        }
        missing = m;
        period = span / (n - 1 + m) as f64;
    }
    Some(Fit {
        period_ns: period,
        missing: missing.min(u32::MAX as u64) as u32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Timestamps jittered by a logger (late then early, up to 1.2 periods apart) give the
    /// ECU's period, where the median interval would not; a real gap is counted.
    #[test]
    fn the_period_survives_jitter_and_gaps_are_counted() {
        let t_ns = 12_060_000.0;
        let jitter = [0.0, 0.45, -0.3, 0.6, 0.1, -0.45, 0.2];
        let times: Vec<i64> = (0..500)
            .map(|i| ((i as f64 + jitter[i % jitter.len()]) * t_ns) as i64)
            .collect();
        let f = fit(times.iter().copied()).unwrap();
        assert!((f.period_ns / t_ns - 1.0).abs() < 1e-3, "{f:?}");
        assert_eq!(f.missing, 0);
        // Drop 5 samples in a row and 3 in a row: 8 missing, same period.
        let gapped: Vec<i64> = times
            .iter()
            .enumerate()
            .filter(|(i, _)| !(100..105).contains(i) && !(300..303).contains(i))
            .map(|(_, t)| *t)
            .collect();
        let g = fit(gapped.iter().copied()).unwrap();
        assert_eq!(g.missing, 8, "{g:?}");
        assert!((g.period_ns / t_ns - 1.0).abs() < 1e-3, "{g:?}");
        assert_eq!(g.slots(6 * t_ns as i64), 6);
        assert_eq!(g.slots((1.9 * t_ns) as i64), 1);
        assert!(fit([5i64].into_iter()).is_none());
        assert!(fit([5i64, 5].into_iter()).is_none());
    }
}
