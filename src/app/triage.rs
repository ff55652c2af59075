//! Triage of a run over a whole benchmark in the pair browser: the paper-style summary rows of
//! the pairs run so far (the same rows, through the same function, as `cgenreg bench` prints),
//! the next / previous failure in the shown order, and the remaining time of a run.

use std::time::Duration;

use crate::app::model::{PairEntry, PairOutcome, PairStatus};
use crate::metrics::FieldSummary;
use crate::report::bench_file::{field_summaries, PairRow};

/// Whether a row counts with the settings in force (`current`; None: every row counts).
fn fresh(p: &PairEntry, current: Option<&str>) -> bool {
    match (&p.settings, current) {
        (Some(s), Some(c)) => s.id == c,
        _ => true,
    }
}

/// A row that ran (registered, or an error) with the settings in force.
pub fn counts(p: &PairEntry, current: Option<&str>) -> bool {
    fresh(p, current)
        && matches!(
            p.outcome(),
            PairOutcome::Success | PairOutcome::Failure | PairOutcome::Done | PairOutcome::Error
        )
}

/// A row as `bench` records the pair: a pair that ran with an error is a failure with no pose.
pub fn bench_row(p: &PairEntry) -> PairRow {
    let error = match &p.status {
        PairStatus::Failed(why) => Some(why.clone()),
        _ => None,
    };
    PairRow {
        id: p.id.clone(),
        split: p.split.clone(),
        rre_deg: p.rre_deg,
        rte_m: p.rte_m,
        inlier_ratio: p.inlier_ratio,
        success: if error.is_some() {
            Some(false)
        } else {
            p.success
        },
        time_s: p.time_ms.unwrap_or(0.0) / 1e3,
        error,
        criterion: p.criterion,
        also: p.also,
        scene: p.scene.clone(),
        rmse_counted: p.rmse_ref.is_some(),
        rmse_m: p.rmse_m,
        ..Default::default()
    }
}

/// The paper-style rows (per benchmark and scene, then each benchmark pooled) of the pairs
/// that ran with the settings in force, computed by `bench`'s own function
/// ([`field_summaries`]); the second value is how many pairs they cover. Pending rows and rows
/// of other settings are left out, so a partial run's rows say so by their pair counts.
pub fn summary_rows(pairs: &[PairEntry], current: Option<&str>) -> (Vec<FieldSummary>, usize) {
    let rows: Vec<PairRow> = pairs
        .iter()
        .filter(|p| counts(p, current))
        .map(bench_row)
        .collect();
    (field_summaries(&rows), rows.len())
}

/// A registration that failed its criterion, or a pair that ran with an error, with the
/// settings in force.
pub fn is_failure(p: &PairEntry, current: Option<&str>) -> bool {
    fresh(p, current) && matches!(p.outcome(), PairOutcome::Failure | PairOutcome::Error)
}

/// The next failure (`forward`) or the previous one after / before the row `from` in `order`
/// (indices into `pairs`, as shown), wrapping around; from the top (or the bottom) when `from`
/// is not in the order. None when no shown row is a failure.
pub fn next_failure(
    pairs: &[PairEntry],
    order: &[usize],
    from: Option<usize>,
    forward: bool,
    current: Option<&str>,
) -> Option<usize> {
    let n = order.len();
    if n == 0 {
        return None;
    }
    let at = from.and_then(|f| order.iter().position(|&i| i == f));
    (1..=n)
        .map(|k| match (at, forward) {
            (Some(a), true) => (a + k) % n,
            (Some(a), false) => (a + n - k % n) % n,
            (None, true) => k - 1,
            (None, false) => n - k,
        })
        .map(|k| order[k])
        .find(|&i| is_failure(&pairs[i], current))
}

/// The remaining time of a run that finished `done` of `total` pairs in `elapsed`, at its mean
/// pace so far (None before the first pair ends).
pub fn eta(elapsed: Duration, done: usize, total: usize) -> Option<Duration> {
    if done == 0 {
        return None;
    }
    let left = total.saturating_sub(done) as f64;
    Some(Duration::from_secs_f64(
        elapsed.as_secs_f64() / done as f64 * left,
    ))
}

/// A duration as "1 h 02 min", "3 min 20 s" or "45 s".
pub fn human_duration(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..=59 => format!("{s} s"),
        60..=3599 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::model::{InspectorModel, SettingsTag};

    fn tag(id: &str) -> Option<SettingsTag> {
        Some(SettingsTag {
            id: id.into(),
            summary: String::new(),
        })
    }

    #[test]
    fn next_failure_walks_the_shown_order_and_wraps() {
        let m = InspectorModel::demo();
        let order: Vec<usize> = (0..m.pairs.len()).collect();
        let fails: Vec<usize> = order
            .iter()
            .copied()
            .filter(|&i| is_failure(&m.pairs[i], None))
            .collect();
        assert!(fails.len() >= 2, "the demo has failures and an error row");
        // forward from nowhere: the first; from each failure: the next, wrapping
        assert_eq!(
            next_failure(&m.pairs, &order, None, true, None),
            Some(fails[0])
        );
        for w in fails.windows(2) {
            assert_eq!(
                next_failure(&m.pairs, &order, Some(w[0]), true, None),
                Some(w[1])
            );
            assert_eq!(
                next_failure(&m.pairs, &order, Some(w[1]), false, None),
                Some(w[0])
            );
        }
        let last = *fails.last().unwrap();
        assert_eq!(
            next_failure(&m.pairs, &order, Some(last), true, None),
            Some(fails[0])
        );
        // backward from nowhere: the last
        assert_eq!(
            next_failure(&m.pairs, &order, None, false, None),
            Some(last)
        );
        // rows of other settings are not failures of the run in force
        let mut stale = m.pairs.clone();
        for p in &mut stale {
            p.settings = tag("old");
        }
        assert_eq!(next_failure(&stale, &order, None, true, Some("new")), None);
        assert_eq!(next_failure(&m.pairs, &[], None, true, None), None);
    }

    #[test]
    fn eta_at_the_mean_pace() {
        assert_eq!(eta(Duration::from_secs(10), 0, 5), None);
        assert_eq!(
            eta(Duration::from_secs(10), 2, 6),
            Some(Duration::from_secs(20))
        );
        assert_eq!(eta(Duration::from_secs(10), 6, 6), Some(Duration::ZERO));
        assert_eq!(human_duration(Duration::from_secs(45)), "45 s");
        assert_eq!(human_duration(Duration::from_secs(200)), "3 min 20 s");
        assert_eq!(human_duration(Duration::from_secs(3720)), "1 h 02 min");
    }
}
