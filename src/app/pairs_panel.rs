//! Pair browser: every pair with its status and metrics, sortable so the worst come first.

use eframe::egui;
use serde::{Deserialize, Serialize};

use super::model::{InspectorModel, PairEntry, PairStatus};
use super::Command;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairSort {
    Name,
    RreWorstFirst,
    RteWorstFirst,
}

/// Row order under a sort: failures and missing metrics count as worst.
pub fn sorted_pairs(pairs: &[PairEntry], sort: PairSort) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..pairs.len()).collect();
    let key = |p: &PairEntry, rre: bool| -> f64 {
        if let PairStatus::Failed(_) = p.status {
            return f64::INFINITY;
        }
        let v = if rre { p.rre_deg } else { p.rte_m };
        v.unwrap_or(f64::NEG_INFINITY)
    };
    match sort {
        PairSort::Name => idx.sort_by(|&a, &b| pairs[a].id.cmp(&pairs[b].id)),
        PairSort::RreWorstFirst => {
            idx.sort_by(|&a, &b| key(&pairs[b], true).total_cmp(&key(&pairs[a], true)))
        }
        PairSort::RteWorstFirst => {
            idx.sort_by(|&a, &b| key(&pairs[b], false).total_cmp(&key(&pairs[a], false)))
        }
    }
    idx
}

pub fn pairs_panel(
    ui: &mut egui::Ui,
    model: &InspectorModel,
    sort: &mut PairSort,
    out: &mut Vec<Command>,
) {
    ui.horizontal(|ui| {
        ui.label("Sort:");
        ui.selectable_value(sort, PairSort::RreWorstFirst, "worst RRE");
        ui.selectable_value(sort, PairSort::RteWorstFirst, "worst RTE");
        ui.selectable_value(sort, PairSort::Name, "name");
    });
    egui::ScrollArea::vertical()
        .id_salt("pairs")
        .max_height(170.0)
        .show(ui, |ui| {
            egui::Grid::new("pairs_grid")
                .striped(true)
                .num_columns(4)
                .show(ui, |ui| {
                    ui.strong("pair");
                    ui.strong("status");
                    ui.strong("RRE °");
                    ui.strong("RTE cm");
                    ui.end_row();
                    for i in sorted_pairs(&model.pairs, *sort) {
                        let p = &model.pairs[i];
                        let current = model.current_pair == Some(i);
                        if ui.selectable_label(current, &p.id).clicked() && !current {
                            out.push(Command::SelectPair(p.id.clone()));
                        }
                        match &p.status {
                            PairStatus::Failed(m) => {
                                ui.colored_label(egui::Color32::from_rgb(240, 80, 70), "failed")
                                    .on_hover_text(m);
                            }
                            s => {
                                ui.label(format!("{s:?}").to_lowercase());
                            }
                        }
                        ui.label(
                            p.rre_deg
                                .map(|v| format!("{v:.2}"))
                                .unwrap_or_else(|| "–".into()),
                        );
                        ui.label(
                            p.rte_m
                                .map(|v| format!("{:.1}", v * 100.0))
                                .unwrap_or_else(|| "–".into()),
                        );
                        ui.end_row();
                    }
                });
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worst_first_puts_failures_then_largest_errors_on_top() {
        let m = InspectorModel::demo();
        let order = sorted_pairs(&m.pairs, PairSort::RreWorstFirst);
        assert!(matches!(m.pairs[order[0]].status, PairStatus::Failed(_)));
        let rres: Vec<f64> = order.iter().filter_map(|&i| m.pairs[i].rre_deg).collect();
        assert!(rres.windows(2).all(|w| w[0] >= w[1]), "{rres:?}");
        // pending pair without metrics sorts last
        assert!(m.pairs[*order.last().unwrap()].rre_deg.is_none());
        let by_rte = sorted_pairs(&m.pairs, PairSort::RteWorstFirst);
        let rtes: Vec<f64> = by_rte.iter().filter_map(|&i| m.pairs[i].rte_m).collect();
        assert!(rtes.windows(2).all(|w| w[0] >= w[1]));
    }
}
