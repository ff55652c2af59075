//! Pair browser: every pair of the dataset with its status and metrics. "Run all" (or only
//! the failed and pending pairs) registers the dataset on the worker with a progress bar, the
//! time left and Cancel, each result filling its row as it comes in; filters (split, scene,
//! outcome, id text), failures first and a sort on any column (click its header) pick and
//! order the rows; Up/Down and j/k open the previous / next pair of that order, n / N the next /
//! previous failure, and the current pair's row is kept in view. Above the rows, the
//! paper-style summary of the pairs run (per benchmark and scene, the numbers `cgenreg bench`
//! prints, by the same function).
//!
//! The side panel holds a compact list (pair, status, RRE, RTE) with the run controls; the
//! "Pairs" tab holds the filters and every column.

use eframe::egui;

use super::{Tab, TabContext};
use crate::app::channel::{Command, RunProgress, RunSelection};
use crate::app::model::{InspectorModel, PairEntry, PairOutcome, PairStatus};
use crate::app::state::Panel;
use crate::app::triage;

mod summary;
mod table;

pub use crate::app::pair_order::{
    sorted_pairs, visible_pairs, OutcomeFilter, PairColumn, PairFilter, PairSort,
};
use summary::go_to_failure;
pub use summary::{failure_buttons, summary_table};
pub use table::common_id_prefix;
use table::{table, ScrollMemo, TableView};

/// The browser's state besides the (persisted) sort.
#[derive(Debug, Default)]
pub struct PairsTab {
    pub filter: PairFilter,
    /// The run in progress (None when none runs).
    pub progress: Option<RunProgress>,
    /// When the run in progress started (its time left is at its mean pace so far).
    run_started: Option<std::time::Instant>,
    /// A pair asked for by the keyboard and not shown yet (the next key moves from it).
    requested: Option<String>,
    /// What each list (side panel, tab) last scrolled to and drew.
    scrolled: [ScrollMemo; 2],
    /// The id of the settings in force ([`crate::app::model::SettingsTag`]): rows computed with
    /// others are marked stale and left out of the counts (None: every row counts).
    pub current_settings: Option<String>,
    /// While a run is in progress: the order and filter the rows were shown with when it
    /// started, and their ids in that order (rows do not move under the cursor as results
    /// come in; a new sort or filter chosen during the run applies at once).
    held: Option<(PairSort, PairFilter, Vec<String>)>,
}

impl PairsTab {
    /// The rows shown (indices into `model.pairs`), filtered and in `sort`'s order; during a
    /// run, in the order they had when the run started.
    pub fn rows(&mut self, model: &InspectorModel, sort: PairSort) -> Vec<usize> {
        let rows = visible_pairs(&model.pairs, &self.filter, sort);
        if self.progress.is_none() {
            self.held = None;
            return rows;
        }
        let stale = self
            .held
            .as_ref()
            .is_none_or(|(s, f, _)| *s != sort || *f != self.filter);
        if stale {
            let ids = rows.iter().map(|&i| model.pairs[i].id.clone()).collect();
            self.held = Some((sort, self.filter.clone(), ids));
        }
        let Some((_, _, ids)) = &self.held else {
            return rows;
        };
        let at: std::collections::HashMap<&str, usize> = ids
            .iter()
            .enumerate()
            .map(|(k, id)| (id.as_str(), k))
            .collect();
        let mut rows = rows;
        // stable: rows that entered the filter since keep their sorted order, at the end
        rows.sort_by_key(|&i| {
            at.get(model.pairs[i].id.as_str())
                .copied()
                .unwrap_or(usize::MAX)
        });
        rows
    }
}

/// Whether a row was computed with other settings than `current`.
pub fn is_stale(row: &PairEntry, current: Option<&str>) -> bool {
    match (&row.settings, current) {
        (Some(s), Some(c)) => s.id != c,
        _ => false,
    }
}

/// Applies a run's progress to the shown model: the finished pair's row, the running mark.
pub fn apply_progress(model: &mut InspectorModel, state: &mut PairsTab, p: RunProgress) {
    if let Some(row) = model.pairs.iter_mut().find(|r| r.id == p.pair) {
        match &p.row {
            Some(new) => *row = new.clone(),
            None => row.status = PairStatus::Running,
        }
    }
    if p.finished {
        state.run_started = None;
    } else if state.progress.is_none() || state.run_started.is_none() {
        state.run_started = Some(std::time::Instant::now());
    }
    state.progress = (!p.finished).then_some(p);
}

/// "2 / 10 · 1 min 20 s left" of a run in progress (the time left once a pair has ended).
pub fn progress_text(p: &RunProgress, started: Option<std::time::Instant>) -> String {
    let left = started
        .and_then(|t| triage::eta(t.elapsed(), p.done, p.total))
        .map(|d| format!(" · {} left", triage::human_duration(d)))
        .unwrap_or_default();
    format!("{} / {}{left}", p.done, p.total)
}

/// Up/Down or k/j: open the previous / next pair of the browser's order (not while a text
/// field has the keyboard, nor during a run); Escape cancels a run.
pub fn keyboard_nav(
    ctx: &egui::Context,
    model: &InspectorModel,
    state: &mut PairsTab,
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
    let (up, down, failure) = ctx.input(|i| {
        let plain = !i.modifiers.any();
        let n = i.key_pressed(egui::Key::N);
        (
            plain && (i.key_pressed(egui::Key::ArrowUp) || i.key_pressed(egui::Key::K)),
            plain && (i.key_pressed(egui::Key::ArrowDown) || i.key_pressed(egui::Key::J)),
            match (n, plain, i.modifiers.shift_only()) {
                (true, true, _) => Some(true),
                (true, false, true) => Some(false),
                _ => None,
            },
        )
    });
    if let Some(forward) = failure {
        if go_to_failure(model, state, sort, forward, out) {
            if let Some(id) = ctx.memory(|m| m.focused()) {
                ctx.memory_mut(|m| m.surrender_focus(id));
            }
        }
        return;
    }
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

/// "Run all" and "Run failed/pending", or the running run's progress bar, time left and
/// Cancel.
pub fn run_controls(ui: &mut egui::Ui, state: &PairsTab, out: &mut Vec<Command>) {
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
                        .desired_width(220.0)
                        .text(progress_text(p, state.run_started)),
                )
                .on_hover_text(format!("now: {}", p.pair));
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

/// The split, scene, outcome and text filters.
pub fn filter_controls(ui: &mut egui::Ui, model: &InspectorModel, filter: &mut PairFilter) {
    let mut splits: Vec<&str> = model
        .pairs
        .iter()
        .map(|p| p.split.as_str())
        .filter(|s| !s.is_empty())
        .collect();
    splits.sort_unstable();
    splits.dedup();
    let mut scenes: Vec<&str> = model
        .pairs
        .iter()
        .filter_map(|p| p.scene.as_deref())
        .collect();
    scenes.sort_unstable();
    scenes.dedup();
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
        if !scenes.is_empty() {
            egui::ComboBox::new("pairs_scene", "scene")
                .selected_text(filter.scene.as_deref().unwrap_or("every scene"))
                .show_ui(ui, |ui| {
                    ui.selectable_value(&mut filter.scene, None, "every scene");
                    for s in scenes {
                        ui.selectable_value(&mut filter.scene, Some(s.to_string()), s);
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
            *filter = filter.cleared();
        }
    });
}

/// The side panel's list: run controls, three quick sorts, pair / status / RRE / RTE.
pub fn pairs_panel(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    state: &mut PairsTab,
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
    let rows = state.rows(model, *sort);
    if state.filter.is_active() {
        ui.weak(format!(
            "{} of {} pairs (filtered in the Pairs tab)",
            rows.len(),
            model.pairs.len()
        ));
    }
    let cols = [
        PairColumn::Pair,
        PairColumn::Status,
        PairColumn::Rre,
        PairColumn::Rte,
    ];
    let view = TableView {
        id: "pairs_grid",
        model,
        rows: &rows,
        columns: &cols,
        max_height: Some(170.0),
        sideways: false,
    };
    let current = state.current_settings.clone();
    table(
        ui,
        view,
        sort,
        &mut state.scrolled[0],
        current.as_deref(),
        out,
    );
    let stale = rows
        .iter()
        .filter(|&&i| is_stale(&model.pairs[i], current.as_deref()))
        .count();
    if stale > 0 {
        ui.weak(format!("{stale} stale rows: computed with other settings"));
    }
}

/// Counts of the outcomes over `rows` computed with the settings in force, as "12 success ·
/// 3 failure · ..."; rows of other settings are counted apart, never mixed in.
pub fn summary(model: &InspectorModel, rows: &[usize], current: Option<&str>) -> String {
    use PairOutcome as O;
    let (stale, fresh): (Vec<usize>, Vec<usize>) = rows
        .iter()
        .partition(|&&i| is_stale(&model.pairs[i], current));
    let count = |o: O| {
        fresh
            .iter()
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
    let mut s = format!(
        "{} pairs with the current settings: {}",
        fresh.len(),
        if parts.is_empty() {
            "none run".to_string()
        } else {
            parts.join(" · ")
        }
    );
    if !stale.is_empty() {
        s.push_str(&format!(
            " · {} stale (other settings, not counted; “Run failed/pending” re-runs them)",
            stale.len()
        ));
    }
    s
}

/// The "Pairs" tab: the run controls, the summary rows, filters, and every column.
impl Tab for PairsTab {
    fn panel(&self) -> Panel {
        Panel::Pairs
    }
    fn ui(&mut self, ui: &mut egui::Ui, cx: &mut TabContext<'_>) {
        let model = cx.shared.model;
        run_controls(ui, self, cx.shared.commands);
        summary_table(ui, model, self);
        ui.separator();
        filter_controls(ui, model, &mut self.filter);
        let sort = &mut cx.shared.ui.pair_sort;
        failure_buttons(ui, model, self, *sort, cx.shared.commands);
        let rows = self.rows(model, *sort);
        ui.label(summary(model, &rows, self.current_settings.as_deref()));
        ui.weak(
            "click a header to sort (again: reverse) · Up/Down or j/k: previous / next pair · \
             n / N: next / previous failure",
        );
        ui.separator();
        let view = TableView {
            id: "pairs_tab_grid",
            model,
            rows: &rows,
            columns: &PairColumn::ALL,
            max_height: None,
            sideways: true,
        };
        let current = self.current_settings.clone();
        table(
            ui,
            view,
            sort,
            &mut self.scrolled[1],
            current.as_deref(),
            cx.shared.commands,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_updates_rows_and_clears_when_finished() {
        let mut m = InspectorModel::demo();
        let mut st = PairsTab::default();
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

    #[test]
    fn rows_keep_their_order_while_a_run_fills_them() {
        let mut m = InspectorModel::demo();
        let mut st = PairsTab::default();
        let sort = PairSort::WORST_RRE;
        let before = st.rows(&m, sort);
        let last = *before.last().unwrap();
        let id = m.pairs[last].id.clone();
        let total = m.pairs.len();
        let progress = |row: Option<PairEntry>, finished| RunProgress {
            done: 0,
            total,
            pair: id.clone(),
            row,
            finished,
            cancelled: false,
        };
        apply_progress(&mut m, &mut st, progress(None, false));
        let running = st.rows(&m, sort);
        // the last row's result comes in as the worst of all: it stays where it was
        let mut row = m.pairs[last].clone();
        row.status = PairStatus::Done;
        row.rre_deg = Some(179.0);
        apply_progress(&mut m, &mut st, progress(Some(row.clone()), false));
        assert_eq!(st.rows(&m, sort), running);
        assert_eq!(*st.rows(&m, sort).last().unwrap(), last);
        // a sort chosen during the run applies at once
        assert_eq!(
            st.rows(&m, PairSort::BY_NAME),
            visible_pairs(&m.pairs, &st.filter, PairSort::BY_NAME)
        );
        // the run ends: the order is the sort's again, the row moved up (behind the error row,
        // whose RRE counts as infinite)
        apply_progress(&mut m, &mut st, progress(Some(row), true));
        let after = st.rows(&m, sort);
        assert_eq!(after, visible_pairs(&m.pairs, &st.filter, sort));
        assert_eq!(after.iter().position(|&i| i == last), Some(1), "{after:?}");
    }
}
