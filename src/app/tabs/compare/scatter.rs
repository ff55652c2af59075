//! The Compare tab's scatter: RRE of A against RRE of B (log axes by default) with the
//! diagonal and the success threshold, one colour per quadrant; clicking a point selects it.

use eframe::egui;
use egui_plot::{
    GridInput, GridMark, HLine, Legend, Line, LineStyle, Plot, PlotPoint, Points, VLine,
};

use super::{flip_color, flip_short, fmt, CompareTab, FLIPS};
use crate::report::compare::{Flip, PairDiff};

/// Smallest RRE drawn on log axes (0.001 deg); smaller values sit on it.
const LOG_FLOOR: f64 = 1e-3;

fn axis_value(v: f64, log: bool) -> f64 {
    if log {
        v.max(LOG_FLOOR).log10()
    } else {
        v
    }
}

/// Grid lines at powers of ten (labelled) and at 2..9 times them (thin).
fn log_marks(input: GridInput) -> Vec<GridMark> {
    let (lo, hi) = input.bounds;
    let mut out = Vec::new();
    if !(lo.is_finite() && hi.is_finite()) || hi - lo > 40.0 {
        return out;
    }
    // marks inside the visible range only (a label at the edge is drawn outside the plot)
    let mut e = lo.floor();
    while e <= hi.ceil() {
        if e >= lo && e <= hi {
            out.push(GridMark {
                value: e,
                step_size: 1.0,
            });
        }
        for k in 2..10 {
            let v = e + (k as f64).log10();
            if v >= lo && v <= hi {
                out.push(GridMark {
                    value: v,
                    step_size: 0.1,
                });
            }
        }
        e += 1.0;
    }
    out
}

fn log_label(mark: GridMark) -> String {
    if (mark.value - mark.value.round()).abs() > 1e-9 {
        return String::new();
    }
    let v = 10f64.powf(mark.value.round());
    if v >= 1.0 {
        format!("{v:.0}")
    } else {
        format!("{v}")
    }
}

/// The scatter of the shown pairs, `side` pixels wide.
pub(super) fn scatter(ui: &mut egui::Ui, st: &mut CompareTab, rows: &[usize], side: f32) {
    let Some(l) = &st.loaded else { return };
    let c = &l.comparison;
    let log = st.log_axes;
    ui.horizontal(|ui| {
        ui.strong("RRE A against RRE B (deg)");
        ui.checkbox(&mut st.log_axes, "log axes");
    });
    let pts: Vec<(&PairDiff, f64, f64)> = rows
        .iter()
        .map(|&i| &c.pairs[i])
        .filter_map(|p| Some((p, p.a.rre_deg?, p.b.rre_deg?)))
        .map(|(p, x, y)| (p, axis_value(x, log), axis_value(y, log)))
        .collect();
    let unplotted = rows.len() - pts.len();
    // the runs' own criterion (an outdoor run: 5° / 2 m), not 3DMatch's
    let crit_of = |r: &super::load::LoadedRun| {
        r.params
            .as_ref()
            .map(|p| p.success.primary)
            .unwrap_or_default()
    };
    let (crit, crit_b) = (crit_of(&l.a), crit_of(&l.b));
    let thr_label = format!("{} deg (success)", crit.max_rre_deg);
    let thr = axis_value(crit.max_rre_deg, log);
    let (mut lo, mut hi) = (thr, thr);
    for &(_, x, y) in &pts {
        lo = lo.min(x).min(y);
        hi = hi.max(x).max(y);
    }
    let pad = if log { 0.2 } else { (hi - lo) * 0.05 + 1.0 };
    let (lo, hi) = (if log { lo - pad } else { 0f64.min(lo) }, hi + pad);
    let h = side - 40.0 - if unplotted > 0 { 18.0 } else { 0.0 };
    let mut plot = Plot::new("compare_scatter")
        .width(side)
        .height(h.max(120.0))
        .legend(Legend::default().position(egui_plot::Corner::LeftTop))
        .x_axis_label("RRE A (deg)")
        .y_axis_label("RRE B (deg)")
        .include_x(lo)
        .include_x(hi)
        .include_y(lo)
        .include_y(hi)
        .allow_scroll(false)
        .show_x(false)
        .show_y(false);
    if log {
        plot = plot
            .x_grid_spacer(log_marks)
            .y_grid_spacer(log_marks)
            .x_axis_formatter(|m, _| log_label(m))
            .y_axis_formatter(|m, _| log_label(m));
    }
    let selected = st.selected.clone();
    let resp = plot.show(ui, |p| {
        p.line(
            Line::new("A = B", vec![[lo, lo], [hi, hi]])
                .color(egui::Color32::from_gray(170))
                .allow_hover(false),
        );
        let thr_color = egui::Color32::from_rgb(230, 190, 60);
        p.vline(
            VLine::new(thr_label.clone(), thr)
                .color(thr_color)
                .style(LineStyle::dashed_loose())
                .allow_hover(false),
        );
        p.hline(
            HLine::new(thr_label.clone(), thr)
                .color(thr_color)
                .style(LineStyle::dashed_loose())
                .allow_hover(false),
        );
        for f in FLIPS {
            let xy: Vec<[f64; 2]> = pts
                .iter()
                .filter(|(q, _, _)| q.flip == f)
                .map(|&(_, x, y)| [x, y])
                .collect();
            if xy.is_empty() {
                continue;
            }
            p.points(
                Points::new(flip_short(f), xy)
                    .color(flip_color(f))
                    .radius(if matches!(f, Flip::Lost | Flip::Gained) {
                        4.5
                    } else {
                        3.0
                    })
                    .filled(true)
                    .allow_hover(false),
            );
        }
        if let Some((_, x, y)) = pts
            .iter()
            .find(|(q, _, _)| Some(&q.id) == selected.as_ref())
        {
            p.points(
                Points::new("selected", vec![[*x, *y]])
                    .color(egui::Color32::WHITE)
                    .radius(8.0)
                    .filled(false)
                    .allow_hover(false),
            );
        }
    });
    // the pair under the pointer (nearest point within 8 px)
    let hovered = resp.response.hover_pos().and_then(|pos| {
        pts.iter()
            .map(|(q, x, y)| {
                let s = resp.transform.position_from_point(&PlotPoint::new(*x, *y));
                (q, s.distance(pos))
            })
            .filter(|(_, d)| *d <= 8.0)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(q, _)| *q)
    });
    if let Some(q) = hovered {
        let text = format!(
            "{}\n{}\nRRE A {} deg, B {} deg",
            q.id,
            q.flip.label(),
            fmt(q.a.rre_deg, 1.0, 2),
            fmt(q.b.rre_deg, 1.0, 2)
        );
        let r = resp.response.clone().on_hover_text_at_pointer(text);
        if r.clicked() {
            st.selected = Some(q.id.clone());
        }
    }
    if unplotted > 0 {
        ui.weak(format!(
            "{unplotted} shown pairs lack an RRE in one run (failed to run): in the table only"
        ));
    }
    ui.weak(format!(
        "success (run A's criterion): RRE <= {} deg and RTE <= {} cm{}",
        crit.max_rre_deg,
        crit.max_rte_m * 100.0,
        if crit_b == crit {
            String::new()
        } else {
            format!("; run B judges by {}", crit_b.label())
        }
    ));
}
