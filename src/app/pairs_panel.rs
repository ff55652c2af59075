//! Pair browser: every pair of the dataset with its status and metrics. "Run all" (or only
//! the failed and pending pairs) registers the dataset on the worker with a progress bar and
//! Cancel; filters (split, outcome, id text) and a sort on any column (click its header) pick
//! and order the rows; Up/Down and j/k open the previous / next pair of that order, and the
//! current pair's row is kept in view.
//!
//! The side panel holds a compact list (pair, status, RRE, RTE) with the run controls; the
//! "Pairs" tab holds the filters and every column.

use eframe::egui;
use serde::{Deserialize, Serialize};

use super::controls::{RunProgress, RunSelection};
use super::model::{InspectorModel, PairEntry, PairOutcome, PairStatus};
use super::Command;

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

/// The rows shown: a split (None: every split), an outcome, and text in the id.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PairFilter {
    pub split: Option<String>,
    pub outcome: OutcomeFilter,
    pub text: String,
}

impl PairFilter {
    pub fn keeps(&self, p: &PairEntry) -> bool {
        self.split.as_ref().is_none_or(|s| p.split == *s)
            && self.outcome.keeps(p.outcome())
            && (self.text.trim().is_empty()
                || p.id
                    .to_lowercase()
                    .contains(&self.text.trim().to_lowercase()))
    }
    pub fn is_active(&self) -> bool {
        *self != PairFilter::default()
    }
}

/// The browser's state besides the (persisted) sort.
#[derive(Debug, Default)]
pub struct PairsState {
    pub filter: PairFilter,
    /// The run in progress (None when none runs).
    pub progress: Option<RunProgress>,
    /// A pair asked for by the keyboard and not shown yet (the next key moves from it).
    requested: Option<String>,
    /// The current pair each list last scrolled to (side panel, tab).
    scrolled: [Option<String>; 2],
}

/// Row order under a sort. RRE and RTE of a pair that could not be registered count as the
/// worst values; a missing value (not run, no GT) sorts last in either direction; ties go by id.
pub fn sorted_pairs(pairs: &[PairEntry], sort: PairSort) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..pairs.len()).collect();
    idx.sort_by(|&a, &b| compare(&pairs[a], &pairs[b], sort));
    idx
}

/// The rows `filter` keeps, in `sort` order.
pub fn visible_pairs(pairs: &[PairEntry], filter: &PairFilter, sort: PairSort) -> Vec<usize> {
    sorted_pairs(pairs, sort)
        .into_iter()
        .filter(|&i| filter.keeps(&pairs[i]))
        .collect()
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

/// Applies a run's progress to the shown model: the finished pair's row, the running mark.
pub fn apply_progress(model: &mut InspectorModel, state: &mut PairsState, p: RunProgress) {
    if let Some(row) = model.pairs.iter_mut().find(|r| r.id == p.pair) {
        match &p.row {
            Some(new) => *row = new.clone(),
            None => row.status = PairStatus::Running,
        }
    }
    state.progress = (!p.finished).then_some(p);
}

/// Up/Down or k/j: open the previous / next pair of the browser's order (not while a text
/// field has the keyboard, nor during a run); Escape cancels a run.
pub fn keyboard_nav(
    ctx: &egui::Context,
    model: &InspectorModel,
    state: &mut PairsState,
    sort: PairSort,
    out: &mut Vec<Command>,
) {
    let current = model
        .current_pair
        .and_then(|i| model.pairs.get(i))
        .map(|p| p.id.clone());
    if state.requested.is_some() && state.requested == current {
        state.requested = None;
    }
    if state.progress.is_some() {
        if ctx.input(|i| i.key_pressed(egui::Key::Escape)) {
            out.push(Command::Cancel);
        }
        return;
    }
    if ctx.text_edit_focused() {
        return;
    }
    let (up, down) = ctx.input(|i| {
        let plain = !i.modifiers.any();
        (
            plain && (i.key_pressed(egui::Key::ArrowUp) || i.key_pressed(egui::Key::K)),
            plain && (i.key_pressed(egui::Key::ArrowDown) || i.key_pressed(egui::Key::J)),
        )
    });
    if up == down {
        return;
    }
    let order = visible_pairs(&model.pairs, &state.filter, sort);
    let from = state.requested.clone().or(current);
    let at = from.and_then(|id| order.iter().position(|&i| model.pairs[i].id == id));
    let next = match (at, down) {
        (Some(a), true) => (a + 1).min(order.len().saturating_sub(1)),
        (Some(a), false) => a.saturating_sub(1),
        (None, _) => 0,
    };
    let Some(p) = order.get(next).map(|&i| &model.pairs[i]) else {
        return;
    };
    if at != Some(next) {
        out.push(Command::SelectPair(p.id.clone()));
        state.requested = Some(p.id.clone());
        // a focused slider would take the same key
        if let Some(id) = ctx.memory(|m| m.focused()) {
            ctx.memory_mut(|m| m.surrender_focus(id));
        }
    }
}

/// "Run all" and "Run failed/pending", or the running run's progress bar and Cancel.
pub fn run_controls(ui: &mut egui::Ui, state: &PairsState, out: &mut Vec<Command>) {
    match &state.progress {
        Some(p) => {
            ui.horizontal(|ui| {
                let f = if p.total == 0 {
                    1.0
                } else {
                    p.done as f32 / p.total as f32
                };
                ui.add(
                    egui::ProgressBar::new(f)
                        .desired_width(180.0)
                        .text(format!("{} / {} · {}", p.done, p.total, p.pair)),
                );
                if ui
                    .button("Cancel")
                    .on_hover_text("stop before the next pair (Esc)")
                    .clicked()
                {
                    out.push(Command::Cancel);
                }
            });
        }
        None => {
            ui.horizontal(|ui| {
                if ui
                    .button("Run all")
                    .on_hover_text(
                        "register every pair with the current settings (cached stages load)",
                    )
                    .clicked()
                {
                    out.push(Command::RunAll(RunSelection::All));
                }
                if ui
                    .button("Run failed/pending")
                    .on_hover_text("register the pairs not run yet, failed or in error")
                    .clicked()
                {
                    out.push(Command::RunAll(RunSelection::FailedOrPending));
                }
            });
        }
    }
}

/// The split, outcome and text filters.
pub fn filter_controls(ui: &mut egui::Ui, model: &InspectorModel, filter: &mut PairFilter) {
    let mut splits: Vec<&str> = model
        .pairs
        .iter()
        .map(|p| p.split.as_str())
        .filter(|s| !s.is_empty())
        .collect();
    splits.sort_unstable();
    splits.dedup();
    ui.horizontal(|ui| {
        if !splits.is_empty() {
            egui::ComboBox::new("pairs_split", "split")
                .selected_text(filter.split.as_deref().unwrap_or("every split"))
                .show_ui(ui, |ui| {
                    ui.selectable_value(&mut filter.split, None, "every split");
                    for s in splits {
                        ui.selectable_value(&mut filter.split, Some(s.to_string()), s);
                    }
                });
        }
        egui::ComboBox::new("pairs_outcome", "show")
            .selected_text(filter.outcome.label())
            .show_ui(ui, |ui| {
                for o in OutcomeFilter::ALL {
                    ui.selectable_value(&mut filter.outcome, o, o.label());
                }
            });
        ui.add(
            egui::TextEdit::singleline(&mut filter.text)
                .hint_text("filter by id")
                .desired_width(160.0),
        );
        if filter.is_active() && ui.small_button("clear").clicked() {
            *filter = PairFilter::default();
        }
    });
}

/// A clickable header cell; the sorted column shows its direction.
fn header(ui: &mut egui::Ui, column: PairColumn, sort: &mut PairSort) {
    let on = sort.column == column;
    let text = match (on, sort.descending) {
        (true, true) => format!("{} v", column.label()),
        (true, false) => format!("{} ^", column.label()),
        (false, _) => column.label().to_string(),
    };
    let r = ui
        .selectable_label(on, egui::RichText::new(text).strong())
        .on_hover_text("sort by this column (again: the other direction)");
    if r.clicked() {
        *sort = sort.clicked(column);
    }
}

fn outcome_color(o: PairOutcome) -> egui::Color32 {
    match o {
        PairOutcome::Success => egui::Color32::from_rgb(110, 200, 110),
        PairOutcome::Failure => egui::Color32::from_rgb(235, 160, 60),
        PairOutcome::Error => egui::Color32::from_rgb(240, 80, 70),
        PairOutcome::Running => egui::Color32::from_rgb(120, 170, 240),
        PairOutcome::Pending | PairOutcome::Done => egui::Color32::from_gray(170),
    }
}

fn status_cell(ui: &mut egui::Ui, p: &PairEntry) {
    let o = p.outcome();
    let r = ui.colored_label(outcome_color(o), o.label());
    if let PairStatus::Failed(m) = &p.status {
        r.on_hover_text(m);
    }
}

fn opt(v: Option<f64>, scale: f64, digits: usize) -> String {
    v.map(|x| format!("{:.*}", digits, x * scale))
        .unwrap_or_else(|| "-".into())
}

/// One cell of a row.
fn cell(ui: &mut egui::Ui, p: &PairEntry, c: PairColumn) {
    match c {
        PairColumn::Pair => {}
        PairColumn::Split => {
            ui.label(&p.split);
        }
        PairColumn::Status => status_cell(ui, p),
        PairColumn::Rre => {
            ui.label(opt(p.rre_deg, 1.0, 2));
        }
        PairColumn::Rte => {
            ui.label(opt(p.rte_m, 100.0, 1));
        }
        PairColumn::InlierRatio => {
            ui.label(opt(p.inlier_ratio, 100.0, 1));
        }
        PairColumn::Correspondences => {
            ui.label(
                p.correspondences
                    .map(|n| n.to_string())
                    .unwrap_or_else(|| "-".into()),
            );
        }
        PairColumn::Time => {
            ui.label(opt(p.time_ms, 1e-3, 2));
        }
    }
}

/// The table: a header of `columns` (the first is the pair id) and one row per shown pair.
/// Clicking an id opens that pair; the current pair's row is scrolled into view when it
/// becomes current.
#[allow(clippy::too_many_arguments)]
fn table(
    ui: &mut egui::Ui,
    id: &str,
    model: &InspectorModel,
    rows: &[usize],
    columns: &[PairColumn],
    sort: &mut PairSort,
    scrolled: &mut Option<String>,
    out: &mut Vec<Command>,
) {
    egui::Grid::new(id)
        .striped(true)
        .num_columns(columns.len())
        .show(ui, |ui| {
            for &c in columns {
                header(ui, c, sort);
            }
            ui.end_row();
            for &i in rows {
                let p = &model.pairs[i];
                let current = model.current_pair == Some(i);
                let r = ui.selectable_label(current, &p.id);
                if r.clicked() && !current {
                    out.push(Command::SelectPair(p.id.clone()));
                }
                if current && scrolled.as_deref() != Some(p.id.as_str()) {
                    // only when hidden (a visible row stays where it is, the header with it)
                    if !ui.clip_rect().contains_rect(r.rect) {
                        r.scroll_to_me_animation(
                            Some(egui::Align::Center),
                            egui::style::ScrollAnimation::none(),
                        );
                    }
                    *scrolled = Some(p.id.clone());
                }
                for &c in &columns[1..] {
                    cell(ui, p, c);
                }
                ui.end_row();
            }
        });
}

/// The side panel's list: run controls, three quick sorts, pair / status / RRE / RTE.
pub fn pairs_panel(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut PairsState,
    sort: &mut PairSort,
    out: &mut Vec<Command>,
) {
    run_controls(ui, state, out);
    ui.horizontal(|ui| {
        ui.label("Sort:");
        ui.selectable_value(sort, PairSort::WORST_RRE, "worst RRE");
        ui.selectable_value(sort, PairSort::WORST_RTE, "worst RTE");
        ui.selectable_value(sort, PairSort::BY_NAME, "name");
    });
    let rows = visible_pairs(&model.pairs, &state.filter, *sort);
    if state.filter.is_active() {
        ui.weak(format!(
            "{} of {} pairs (filtered in the Pairs tab)",
            rows.len(),
            model.pairs.len()
        ));
    }
    egui::ScrollArea::vertical()
        .id_salt("pairs")
        .max_height(170.0)
        .show(ui, |ui| {
            let cols = [
                PairColumn::Pair,
                PairColumn::Status,
                PairColumn::Rre,
                PairColumn::Rte,
            ];
            table(
                ui,
                "pairs_grid",
                model,
                &rows,
                &cols,
                sort,
                &mut state.scrolled[0],
                out,
            );
        });
}

/// Counts of the outcomes over `rows`, as "12 success · 3 failure · ...".
fn summary(model: &InspectorModel, rows: &[usize]) -> String {
    use PairOutcome as O;
    let count = |o: O| {
        rows.iter()
            .filter(|&&i| model.pairs[i].outcome() == o)
            .count()
    };
    let parts: Vec<String> = [
        O::Success,
        O::Failure,
        O::Error,
        O::Done,
        O::Running,
        O::Pending,
    ]
    .into_iter()
    .map(|o| (o, count(o)))
    .filter(|(_, n)| *n > 0)
    .map(|(o, n)| format!("{n} {}", o.label()))
    .collect();
    format!("{} pairs: {}", rows.len(), parts.join(" · "))
}

/// The "Pairs" tab: filters, a summary, and every column.
pub fn pairs_tab(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut PairsState,
    sort: &mut PairSort,
    out: &mut Vec<Command>,
) {
    filter_controls(ui, model, &mut state.filter);
    let rows = visible_pairs(&model.pairs, &state.filter, *sort);
    ui.label(summary(model, &rows));
    ui.weak("click a header to sort (again: reverse) · Up/Down or j/k: previous / next pair");
    ui.separator();
    egui::ScrollArea::both()
        .id_salt("pairs_tab")
        .auto_shrink([false, false])
        .show(ui, |ui| {
            table(
                ui,
                "pairs_tab_grid",
                model,
                &rows,
                &PairColumn::ALL,
                sort,
                &mut state.scrolled[1],
                out,
            );
        });
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn progress_updates_rows_and_clears_when_finished() {
        let mut m = InspectorModel::demo();
        let mut st = PairsState::default();
        let id = m.pairs[8].id.clone();
        let p = |row: Option<PairEntry>, finished| RunProgress {
            done: 0,
            total: 1,
            pair: id.clone(),
            row,
            finished,
            cancelled: false,
        };
        apply_progress(&mut m, &mut st, p(None, false));
        assert_eq!(m.pairs[8].status, PairStatus::Running);
        assert!(st.progress.is_some());
        let mut row = m.pairs[8].clone();
        row.status = PairStatus::Done;
        row.rre_deg = Some(1.0);
        apply_progress(&mut m, &mut st, p(Some(row.clone()), true));
        assert_eq!(m.pairs[8], row);
        assert!(st.progress.is_none());
    }
}
