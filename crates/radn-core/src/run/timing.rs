//! Where a whole run's time goes, per stage, summed over its frames: every stage that times
//! itself adds here (OIDN's filters, decoding, the network's stages, the temporal pass,
//! writing), and `radn denoise -v` prints the sums at the end. Stages are named by the code
//! that times them; the first to report comes first.

use std::sync::Mutex;
use std::time::{Duration, Instant};

static TALLY: Mutex<Vec<(&'static str, Duration)>> = Mutex::new(Vec::new());

/// Adds `elapsed` to `stage`.
pub fn add(stage: &'static str, elapsed: Duration) {
    let mut t = TALLY.lock().unwrap_or_else(|p| p.into_inner());
    match t.iter_mut().find(|(s, _)| *s == stage) {
        Some((_, d)) => *d += elapsed,
        None => t.push((stage, elapsed)),
    }
}

/// Runs `f`, adding its wall time to `stage`.
pub fn timed<T>(stage: &'static str, f: impl FnOnce() -> T) -> T {
    let started = Instant::now();
    let out = f();
    add(stage, started.elapsed());
    out
}

/// The sums since the last call, cleared.
pub fn take() -> Vec<(&'static str, Duration)> {
    std::mem::take(&mut *TALLY.lock().unwrap_or_else(|p| p.into_inner()))
}

/// One line per stage: its seconds, its share of `wall`, and seconds per frame of `frames`.
pub fn report(stages: &[(&'static str, Duration)], wall: Duration, frames: usize) -> String {
    let mut lines = Vec::new();
    let counted: Duration = stages.iter().map(|(_, d)| *d).sum();
    let rows = stages
        .iter()
        .copied()
        .chain(std::iter::once(("other", wall.saturating_sub(counted))));
    for (stage, d) in rows {
        lines.push(format!(
            "  {stage:<20} {:>8.2} s {:>5.1} % {:>7.2} s per frame",
            d.as_secs_f64(),
            100.0 * d.as_secs_f64() / wall.as_secs_f64().max(1e-9),
            d.as_secs_f64() / frames.max(1) as f64
        ));
    }
    lines.join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_sum_in_order_and_the_report_accounts_for_the_wall_time() {
        // other tests of this binary may time stages meanwhile: only these two are looked at
        let (a, b) = ("timing test a", "timing test b");
        add(b, Duration::from_millis(300));
        add(a, Duration::from_millis(100));
        add(b, Duration::from_millis(200));
        let t: Vec<_> = take()
            .into_iter()
            .filter(|(s, _)| [a, b].contains(s))
            .collect();
        assert_eq!(
            t,
            vec![
                (b, Duration::from_millis(500)),
                (a, Duration::from_millis(100))
            ]
        );
        assert!(!take().iter().any(|(s, _)| [a, b].contains(s)));
        let r = report(&t, Duration::from_secs(1), 2);
        let lines: Vec<&str> = r.lines().collect();
        assert_eq!(lines.len(), 3);
        assert!(
            lines[0].contains("0.50 s") && lines[0].contains("50.0 %"),
            "{r}"
        );
        assert!(
            lines[2].starts_with("  other") && lines[2].contains("0.40 s"),
            "{r}"
        );
        assert!(lines[0].contains("0.25 s per frame"), "{r}");
    }
}
