//! The pair browser's order and filters: the columns, a sort on any of them (parsed from
//! `--sort`, toggled by a header click, loaded from older settings files), and the split /
//! outcome / text filters.

use serde::{Deserialize, Serialize};

use crate::app::model::{PairEntry, PairOutcome, PairStatus};

/// A column of the pair browser.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairColumn {
    Pair,
    Split,
    Status,
    Rre,
    Rte,
    InlierRatio,
    Correspondences,
    Time,
}

impl PairColumn {
    pub const ALL: [PairColumn; 8] = [
        Self::Pair,
        Self::Split,
        Self::Status,
        Self::Rre,
        Self::Rte,
        Self::InlierRatio,
        Self::Correspondences,
        Self::Time,
    ];
    /// The header text.
    pub fn label(self) -> &'static str {
        match self {
            Self::Pair => "pair",
            Self::Split => "split",
            Self::Status => "status",
            Self::Rre => "RRE °",
            Self::Rte => "RTE cm",
            Self::InlierRatio => "inliers %",
            Self::Correspondences => "corr.",
            Self::Time => "time s",
        }
    }
    /// The name on the command line (`--sort rre:desc`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Pair => "pair",
            Self::Split => "split",
            Self::Status => "status",
            Self::Rre => "rre",
            Self::Rte => "rte",
            Self::InlierRatio => "inliers",
            Self::Correspondences => "corr",
            Self::Time => "time",
        }
    }
}

/// The browser's order: a column, ascending or descending.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct PairSort {
    pub column: PairColumn,
    pub descending: bool,
}

impl Default for PairSort {
    /// Worst RRE first.
    fn default() -> Self {
        Self::WORST_RRE
    }
}

impl PairSort {
    pub const WORST_RRE: PairSort = PairSort {
        column: PairColumn::Rre,
        descending: true,
    };
    pub const WORST_RTE: PairSort = PairSort {
        column: PairColumn::Rte,
        descending: true,
    };
    pub const BY_NAME: PairSort = PairSort {
        column: PairColumn::Pair,
        descending: false,
    };

    /// `COLUMN[:asc|:desc]` with COLUMN one of pair, split, status, rre, rte, inliers, corr,
    /// time (ascending when no direction is given).
    pub fn parse(s: &str) -> Result<PairSort, String> {
        let (col, dir) = s.split_once(':').unwrap_or((s, "asc"));
        let names: Vec<&str> = PairColumn::ALL.iter().map(|c| c.name()).collect();
        let column = PairColumn::ALL
            .into_iter()
            .find(|c| c.name().eq_ignore_ascii_case(col.trim()))
            .ok_or_else(|| {
                format!(
                    "{s:?}: unknown column; expected one of {}",
                    names.join(", ")
                )
            })?;
        let descending = match dir.trim().to_ascii_lowercase().as_str() {
            "asc" => false,
            "desc" => true,
            d => return Err(format!("{s:?}: direction {d:?}, expected asc or desc")),
        };
        Ok(PairSort { column, descending })
    }

    /// Clicking a header: that column, or the other direction when it is already sorted by it.
    pub fn clicked(self, column: PairColumn) -> PairSort {
        if self.column == column {
            PairSort {
                column,
                descending: !self.descending,
            }
        } else {
            PairSort {
                column,
                // metrics start worst first, names and splits A to Z
                descending: !matches!(
                    column,
                    PairColumn::Pair | PairColumn::Split | PairColumn::Status
                ),
            }
        }
    }
}

/// Settings files before the sortable columns stored one of three sorts by name.
impl<'de> Deserialize<'de> for PairSort {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Repr {
            Now {
                column: PairColumn,
                descending: bool,
            },
            Before(Before),
        }
        #[derive(Deserialize)]
        enum Before {
            Name,
            RreWorstFirst,
            RteWorstFirst,
        }
        Ok(match Repr::deserialize(d)? {
            Repr::Now { column, descending } => PairSort { column, descending },
            Repr::Before(Before::Name) => PairSort::BY_NAME,
            Repr::Before(Before::RreWorstFirst) => PairSort::WORST_RRE,
            Repr::Before(Before::RteWorstFirst) => PairSort::WORST_RTE,
        })
    }
}

/// Which outcomes the browser shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OutcomeFilter {
    #[default]
    All,
    Success,
    /// Registered outside the thresholds, or not registered at all.
    FailureOrError,
    Error,
    /// Not run yet (or running).
    Pending,
}

impl OutcomeFilter {
    pub const ALL: [OutcomeFilter; 5] = [
        Self::All,
        Self::Success,
        Self::FailureOrError,
        Self::Error,
        Self::Pending,
    ];
    pub fn label(self) -> &'static str {
        match self {
            Self::All => "all",
            Self::Success => "success",
            Self::FailureOrError => "failure or error",
            Self::Error => "error",
            Self::Pending => "pending",
        }
    }
    pub fn keeps(self, o: PairOutcome) -> bool {
        use PairOutcome as O;
        match self {
            Self::All => true,
            Self::Success => o == O::Success,
            Self::FailureOrError => matches!(o, O::Failure | O::Error),
            Self::Error => o == O::Error,
            Self::Pending => matches!(o, O::Pending | O::Running),
        }
    }
}

/// The rows shown: a split and a scene (None: every one), an outcome, and text in the id; and
/// whether failures (registered outside the criterion, or errors) come first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PairFilter {
    pub split: Option<String>,
    pub scene: Option<String>,
    pub outcome: OutcomeFilter,
    pub text: String,
    /// Failures and errors above every other row, each part in the sort's order (an order,
    /// not a filter: it hides nothing).
    pub failures_first: bool,
}

impl PairFilter {
    pub fn keeps(&self, p: &PairEntry) -> bool {
        self.split.as_ref().is_none_or(|s| p.split == *s)
            && self
                .scene
                .as_ref()
                .is_none_or(|s| p.scene.as_deref() == Some(s.as_str()))
            && self.outcome.keeps(p.outcome())
            && (self.text.trim().is_empty()
                || p.id
                    .to_lowercase()
                    .contains(&self.text.trim().to_lowercase()))
    }
    /// Whether it hides rows (the failures-first order hides none).
    pub fn is_active(&self) -> bool {
        *self
            != PairFilter {
                failures_first: self.failures_first,
                ..PairFilter::default()
            }
    }

    /// No row hidden; the order kept.
    pub fn cleared(&self) -> PairFilter {
        PairFilter {
            failures_first: self.failures_first,
            ..PairFilter::default()
        }
    }
}

/// A row the failures-first order puts on top.
fn is_failure(p: &PairEntry) -> bool {
    matches!(p.outcome(), PairOutcome::Failure | PairOutcome::Error)
}

/// Row order under a sort. RRE and RTE of a pair that could not be registered count as the
/// worst values; a missing value (not run, no GT) sorts last in either direction; ties go by id.
pub fn sorted_pairs(pairs: &[PairEntry], sort: PairSort) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..pairs.len()).collect();
    idx.sort_by(|&a, &b| compare(&pairs[a], &pairs[b], sort));
    idx
}

/// The rows `filter` keeps, in `sort` order (failures first when it asks for it).
pub fn visible_pairs(pairs: &[PairEntry], filter: &PairFilter, sort: PairSort) -> Vec<usize> {
    let mut rows: Vec<usize> = sorted_pairs(pairs, sort)
        .into_iter()
        .filter(|&i| filter.keeps(&pairs[i]))
        .collect();
    if filter.failures_first {
        // stable: each part keeps the sort's order
        rows.sort_by_key(|&i| !is_failure(&pairs[i]));
    }
    rows
}

fn outcome_rank(o: PairOutcome) -> u8 {
    match o {
        PairOutcome::Success => 0,
        PairOutcome::Done => 1,
        PairOutcome::Failure => 2,
        PairOutcome::Error => 3,
        PairOutcome::Running => 4,
        PairOutcome::Pending => 5,
    }
}

/// A numeric column's value (None: missing).
fn value(p: &PairEntry, c: PairColumn) -> Option<f64> {
    let error = matches!(p.status, PairStatus::Failed(_));
    match c {
        PairColumn::Rre if error => Some(f64::INFINITY),
        PairColumn::Rte if error => Some(f64::INFINITY),
        PairColumn::Rre => p.rre_deg,
        PairColumn::Rte => p.rte_m,
        PairColumn::InlierRatio => p.inlier_ratio,
        PairColumn::Correspondences => p.correspondences.map(|n| n as f64),
        PairColumn::Time => p.time_ms,
        _ => None,
    }
}

fn compare(a: &PairEntry, b: &PairEntry, sort: PairSort) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let dir = |o: Ordering| if sort.descending { o.reverse() } else { o };
    let primary = match sort.column {
        PairColumn::Pair => dir(a.id.cmp(&b.id)),
        PairColumn::Split => dir(a.split.cmp(&b.split)),
        PairColumn::Status => dir(outcome_rank(a.outcome()).cmp(&outcome_rank(b.outcome()))),
        c => match (value(a, c), value(b, c)) {
            (Some(x), Some(y)) => dir(x.total_cmp(&y)),
            (Some(_), None) => Ordering::Less,
            (None, Some(_)) => Ordering::Greater,
            (None, None) => Ordering::Equal,
        },
    };
    primary.then_with(|| a.id.cmp(&b.id))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::model::InspectorModel;

    #[test]
    fn worst_first_puts_failures_then_largest_errors_on_top() {
        let m = InspectorModel::demo();
        let order = sorted_pairs(&m.pairs, PairSort::WORST_RRE);
        assert!(matches!(m.pairs[order[0]].status, PairStatus::Failed(_)));
        let rres: Vec<f64> = order.iter().filter_map(|&i| m.pairs[i].rre_deg).collect();
        assert!(rres.windows(2).all(|w| w[0] >= w[1]), "{rres:?}");
        // pending pair without metrics sorts last
        assert!(m.pairs[*order.last().unwrap()].rre_deg.is_none());
        let by_rte = sorted_pairs(&m.pairs, PairSort::WORST_RTE);
        let rtes: Vec<f64> = by_rte.iter().filter_map(|&i| m.pairs[i].rte_m).collect();
        assert!(rtes.windows(2).all(|w| w[0] >= w[1]));
    }

    #[test]
    fn every_column_sorts_both_ways_with_missing_values_last() {
        let m = InspectorModel::demo();
        for c in PairColumn::ALL {
            for descending in [false, true] {
                let s = PairSort {
                    column: c,
                    descending,
                };
                let order = sorted_pairs(&m.pairs, s);
                assert_eq!(order.len(), m.pairs.len());
                let vals: Vec<Option<f64>> = order.iter().map(|&i| value(&m.pairs[i], c)).collect();
                if let Some(first_none) = vals.iter().position(|v| v.is_none()) {
                    if !matches!(c, PairColumn::Pair | PairColumn::Split | PairColumn::Status) {
                        assert!(
                            vals[first_none..].iter().all(|v| v.is_none()),
                            "{c:?} {vals:?}"
                        );
                    }
                }
                let nums: Vec<f64> = vals.into_iter().flatten().collect();
                assert!(
                    nums.windows(2).all(|w| if descending {
                        w[0] >= w[1]
                    } else {
                        w[0] <= w[1]
                    }),
                    "{c:?} desc={descending}: {nums:?}"
                );
            }
        }
        let ids: Vec<&str> = sorted_pairs(&m.pairs, PairSort::BY_NAME)
            .iter()
            .map(|&i| m.pairs[i].id.as_str())
            .collect();
        assert!(ids.windows(2).all(|w| w[0] <= w[1]));
    }

    #[test]
    fn sort_parses_clicks_toggle_and_old_settings_load() {
        assert_eq!(PairSort::parse("rre:desc").unwrap(), PairSort::WORST_RRE);
        assert_eq!(
            PairSort::parse("time").unwrap(),
            PairSort {
                column: PairColumn::Time,
                descending: false
            }
        );
        assert!(PairSort::parse("speed").unwrap_err().contains("rre"));
        assert!(PairSort::parse("rre:up").is_err());
        let s = PairSort::WORST_RRE.clicked(PairColumn::Rre);
        assert_eq!(s.column, PairColumn::Rre);
        assert!(!s.descending);
        assert_eq!(
            PairSort::WORST_RRE.clicked(PairColumn::Pair),
            PairSort::BY_NAME
        );
        let old: PairSort = serde_json::from_str("\"RteWorstFirst\"").unwrap();
        assert_eq!(old, PairSort::WORST_RTE);
        let now = serde_json::to_string(&PairSort::BY_NAME).unwrap();
        assert_eq!(
            serde_json::from_str::<PairSort>(&now).unwrap(),
            PairSort::BY_NAME
        );
    }

    #[test]
    fn filters_keep_split_outcome_and_text() {
        let m = InspectorModel::demo();
        let all = visible_pairs(&m.pairs, &PairFilter::default(), PairSort::BY_NAME);
        assert_eq!(all.len(), m.pairs.len());
        let lo = PairFilter {
            split: Some("3DLoMatch".into()),
            ..Default::default()
        };
        let rows = visible_pairs(&m.pairs, &lo, PairSort::BY_NAME);
        assert!(!rows.is_empty() && rows.iter().all(|&i| m.pairs[i].split == "3DLoMatch"));
        let err = PairFilter {
            outcome: OutcomeFilter::Error,
            ..Default::default()
        };
        let rows = visible_pairs(&m.pairs, &err, PairSort::BY_NAME);
        assert_eq!(rows.len(), 1);
        assert!(matches!(m.pairs[rows[0]].status, PairStatus::Failed(_)));
        let pending = PairFilter {
            outcome: OutcomeFilter::Pending,
            ..Default::default()
        };
        assert_eq!(
            visible_pairs(&m.pairs, &pending, PairSort::BY_NAME).len(),
            1
        );
        let text = PairFilter {
            text: "PAIR-3".into(),
            ..Default::default()
        };
        let rows = visible_pairs(&m.pairs, &text, PairSort::BY_NAME);
        assert_eq!(rows.len(), 1);
        assert!(m.pairs[rows[0]].id.contains("pair-3"));
    }

    #[test]
    fn scene_filter_and_failures_first() {
        let mut m = InspectorModel::demo();
        for (k, p) in m.pairs.iter_mut().enumerate() {
            p.scene = Some(if k % 2 == 0 { "kitchen" } else { "office" }.into());
        }
        let kitchen = PairFilter {
            scene: Some("kitchen".into()),
            ..Default::default()
        };
        let rows = visible_pairs(&m.pairs, &kitchen, PairSort::BY_NAME);
        assert_eq!(rows.len(), m.pairs.len().div_ceil(2));
        assert!(rows
            .iter()
            .all(|&i| m.pairs[i].scene.as_deref() == Some("kitchen")));
        assert!(kitchen.is_active());
        // failures first: an order, not a filter; each part keeps the sort's order
        let first = PairFilter {
            failures_first: true,
            ..Default::default()
        };
        assert!(!first.is_active());
        let plain = visible_pairs(&m.pairs, &PairFilter::default(), PairSort::BY_NAME);
        let rows = visible_pairs(&m.pairs, &first, PairSort::BY_NAME);
        assert_eq!(rows.len(), plain.len());
        let fails = rows
            .iter()
            .take_while(|&&i| is_failure(&m.pairs[i]))
            .count();
        assert!(fails >= 2, "{rows:?}");
        assert!(rows[fails..].iter().all(|&i| !is_failure(&m.pairs[i])));
        let part = |f: bool| -> Vec<usize> {
            plain
                .iter()
                .copied()
                .filter(|&i| is_failure(&m.pairs[i]) == f)
                .collect()
        };
        assert_eq!(rows[..fails], part(true)[..]);
        assert_eq!(rows[fails..], part(false)[..]);
        // clearing keeps the order
        let both = PairFilter {
            failures_first: true,
            ..kitchen
        };
        assert_eq!(both.cleared(), first);
    }
}
