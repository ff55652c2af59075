//! Two settings compared over the open dataset: what the Compare tab asks the worker for and
//! what the worker sends back (plain data).

use crate::pipeline::params::RegisterParams;
use crate::report::compare::BenchRun;

/// One of the two runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    A,
    B,
}

impl Side {
    pub fn label(self) -> &'static str {
        match self {
            Side::A => "A",
            Side::B => "B",
        }
    }
}

/// What the worker is asked to run: the open dataset's pairs with `a`, then with `b`.
#[derive(Clone, Debug, PartialEq)]
pub struct SettingsCompareRequest {
    pub a: RegisterParams,
    pub b: RegisterParams,
    /// The pairs, in order; None: every pair of the open dataset.
    pub pairs: Option<Vec<String>>,
}

/// The two runs a settings comparison made, as bench runs (rows of the pairs that ran).
#[derive(Clone, Debug, PartialEq)]
pub struct SettingsRuns {
    pub a: BenchRun,
    pub b: BenchRun,
    pub request: SettingsCompareRequest,
    /// Stopped by Cancel: the runs hold the pairs that ran under both settings.
    pub cancelled: bool,
}

/// What the worker reports of a settings comparison.
#[derive(Clone, Debug, PartialEq)]
pub enum CompareEvent {
    /// `pair` starts under settings `side`; `done` of `total` registrations (both settings
    /// together) have finished.
    Progress {
        side: Side,
        pair: String,
        done: usize,
        total: usize,
    },
    /// The comparison ended (finished or cancelled).
    Finished(Box<SettingsRuns>),
}
