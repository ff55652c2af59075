//! The Compare tab's table: one row per shown pair (ids coloured by quadrant, both runs'
//! outcomes, RRE / RTE and their differences), a header that stays above the scrolled rows
//! and sorts on a click.

use eframe::egui;

use super::{flip_color, fmt, CompareTab};
use crate::report::compare::{Flip, PairOrder};

/// Column widths of the table (pixels); the six number columns share what is left.
const ID_W: f32 = 140.0;
const FLAG_W: f32 = 30.0;

/// The table of the shown pairs; clicking an id selects the pair.
pub(super) fn table(ui: &mut egui::Ui, st: &mut CompareTab, rows: &[usize]) {
    let Some(l) = &st.loaded else { return };
    let c = &l.comparison;
    let gap = ui.spacing().item_spacing.x;
    let num_w =
        ((ui.available_width() - ID_W - 2.0 * FLAG_W - 9.0 * gap - 12.0) / 6.0).clamp(38.0, 70.0);
    let cols: [(&str, PairOrder, f32); 9] = [
        ("pair", PairOrder::Id, ID_W),
        ("A", PairOrder::Flip, FLAG_W),
        ("B", PairOrder::Flip, FLAG_W),
        ("RRE A", PairOrder::RreA, num_w),
        ("RRE B", PairOrder::RreB, num_w),
        ("dRRE", PairOrder::DRre, num_w),
        ("RTE A", PairOrder::RteA, num_w),
        ("RTE B", PairOrder::RteB, num_w),
        ("dRTE", PairOrder::DRte, num_w),
    ];
    ui.horizontal(|ui| {
        ui.strong(format!("{} pairs shown", rows.len()));
        if ui
            .selectable_label(st.order == PairOrder::FlippedFirst, "flipped first")
            .on_hover_text("gained or lost pairs first, then by |dRRE|")
            .clicked()
        {
            st.order = PairOrder::FlippedFirst;
            st.descending = false;
        }
        ui.weak("RRE in deg, RTE in cm, d = B - A; click a header to sort");
    });
    let mut sort_click = None;
    ui.horizontal(|ui| {
        for (i, (name, order, w)) in cols.iter().enumerate() {
            // the two status columns sort together; mark only the first
            let mark = if st.order == *order && i != 2 {
                if st.descending {
                    " v"
                } else {
                    " ^"
                }
            } else {
                ""
            };
            let r = ui.add_sized(
                [*w, 18.0],
                egui::Button::new(egui::RichText::new(format!("{name}{mark}")).strong())
                    .frame(false),
            );
            if r.clicked() {
                sort_click = Some(*order);
            }
        }
    });
    if let Some(o) = sort_click {
        if st.order == o {
            st.descending = !st.descending;
        } else {
            st.order = o;
            // errors: largest first
            st.descending = !matches!(o, PairOrder::Id | PairOrder::Flip);
        }
    }
    let row_h = ui.spacing().interact_size.y;
    let mut clicked = None;
    egui::ScrollArea::vertical()
        .id_salt("compare_table")
        .auto_shrink([false, false])
        .show_rows(ui, row_h, rows.len(), |ui, range| {
            for &i in &rows[range] {
                let p = &c.pairs[i];
                ui.horizontal(|ui| {
                    let sel = st.selected.as_deref() == Some(p.id.as_str());
                    let id = egui::RichText::new(&p.id).color(flip_color(p.flip));
                    if ui
                        .add_sized([ID_W, row_h], egui::Button::selectable(sel, id))
                        .on_hover_text(p.flip.label())
                        .clicked()
                    {
                        clicked = Some(p.id.clone());
                    }
                    for r in [&p.a, &p.b] {
                        let (t, col) = match (r.success, &r.error) {
                            (_, Some(e)) if !e.is_empty() => {
                                ("err", egui::Color32::from_rgb(240, 80, 70))
                            }
                            (Some(true), _) => ("ok", flip_color(Flip::BothSuccess)),
                            (Some(false), _) => ("fail", flip_color(Flip::Lost)),
                            (None, _) => ("-", egui::Color32::GRAY),
                        };
                        let cell = ui.add_sized(
                            [FLAG_W, row_h],
                            egui::Label::new(egui::RichText::new(t).color(col)),
                        );
                        if let Some(e) = &r.error {
                            cell.on_hover_text(e);
                        }
                    }
                    for (v, scale, d) in [
                        (p.a.rre_deg, 1.0, 2),
                        (p.b.rre_deg, 1.0, 2),
                        (p.d_rre_deg, 1.0, 2),
                        (p.a.rte_m, 100.0, 1),
                        (p.b.rte_m, 100.0, 1),
                        (p.d_rte_m, 100.0, 1),
                    ] {
                        ui.add_sized([num_w, row_h], egui::Label::new(fmt(v, scale, d)));
                    }
                });
            }
        });
    if let Some(id) = clicked {
        st.selected = Some(id);
    }
}
