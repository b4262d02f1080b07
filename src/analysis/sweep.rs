//! Parameter sweeps on all cores, and the small statistics sweeps report (MODEL.md §11, §13:
//! "compare means over seeds").
//!
//! What it is: [`par_map`] runs a closure over a list of parameter points on a fixed number of
//! scoped threads that pull the next point from a shared counter (so slow points do not leave a
//! core idle), and returns results in input order; [`linspace`] and [`MeanStd`] build grids and
//! summarise seeds. What it is not: a scheduler across machines, nor a cache — rerun is the
//! only way to get a result again.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Threads to use by default: `SHIMMY_THREADS` if set to a positive number, else the number of
/// cores the OS offers.
pub fn default_threads() -> usize {
    std::env::var("SHIMMY_THREADS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|n| *n > 0)
        .unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        })
}

/// `f` applied to every item, on `threads` threads (at least 1, at most one per item), results
/// in input order. A panic in `f` propagates to the caller after the other threads stop.
pub fn par_map<P, R, F>(items: &[P], threads: usize, f: F) -> Vec<R>
where
    P: Sync,
    R: Send,
    F: Fn(&P) -> R + Sync,
{
    let threads = threads.clamp(1, items.len().max(1));
    if threads == 1 {
        return items.iter().map(&f).collect();
    }
    let next = AtomicUsize::new(0);
    let slots: Mutex<Vec<Option<R>>> = Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(item) = items.get(i) else { break };
                let r = f(item);
                slots.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(r);
            });
        }
    });
    slots
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .map(|r| r.expect("every sweep point ran (a panic would have propagated)"))
        .collect()
}

/// `n` evenly spaced values from `a` to `b` inclusive (`[a]` for n = 1, empty for n = 0).
pub fn linspace(a: f64, b: f64, n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![a],
        _ => (0..n)
            .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
            .collect(),
    }
}

/// Mean and sample standard deviation of a set of runs (e.g. seeds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeanStd {
    pub mean: f64,
    /// Sample standard deviation (n − 1); 0 for a single value.
    pub std: f64,
    pub n: usize,
}

impl MeanStd {
    /// Mean and std of the finite values in `x`; `None` when there are none.
    pub fn of(x: &[f64]) -> Option<Self> {
        let v: Vec<f64> = x.iter().copied().filter(|v| v.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        let n = v.len();
        let mean = v.iter().sum::<f64>() / n as f64;
        let std = if n > 1 {
            (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1) as f64).sqrt()
        } else {
            0.0
        };
        Some(Self { mean, std, n })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn par_map_keeps_order_and_uses_threads() {
        let items: Vec<u64> = (0..50).collect();
        let ids = Mutex::new(std::collections::HashSet::new());
        let out = par_map(&items, 2, |x| {
            ids.lock().unwrap().insert(std::thread::current().id());
            std::thread::sleep(std::time::Duration::from_millis(2));
            x * x
        });
        assert_eq!(out, items.iter().map(|x| x * x).collect::<Vec<_>>());
        assert_eq!(ids.lock().unwrap().len(), 2);
        assert!(par_map(&Vec::<u8>::new(), 4, |x| *x).is_empty());
    }

    #[test]
    fn linspace_and_stats() {
        assert_eq!(linspace(0.0, 1.0, 3), vec![0.0, 0.5, 1.0]);
        assert!(linspace(0.0, 1.0, 0).is_empty());
        let s = MeanStd::of(&[1.0, 2.0, 3.0, f64::NAN]).unwrap();
        assert_eq!((s.mean, s.std, s.n), (2.0, 1.0, 3));
        assert!(MeanStd::of(&[]).is_none());
    }
}
