//! The x axis of the Plots tab's bar charts: one grid mark per bar and labels wherever they fit.

/// Grid marks for a bar chart with one bar group per integer x: a mark at every bar, each
/// with the largest of 1, 2, 5, 10, 20, ... that divides its index as its step, so that
/// egui_plot labels every bar whose label fits ([`bar_axis`]) and, where they do not all fit,
/// every 2nd, 5th or 10th.
pub(super) fn every_bar(input: egui_plot::GridInput) -> Vec<egui_plot::GridMark> {
    let (lo, hi) = input.bounds;
    let (first, last) = (lo.ceil().max(0.0) as i64, hi.floor() as i64);
    if last < first || last - first > 10_000 {
        return Vec::new();
    }
    (first..=last)
        .map(|v| {
            let mut step = 1i64;
            for s in [2, 5, 10, 20, 50, 100, 200, 500, 1000] {
                if v % s == 0 {
                    step = s;
                }
            }
            egui_plot::GridMark {
                value: v as f64,
                step_size: step as f64,
            }
        })
        .collect()
}

/// The x axis of a bar chart: `label`, the bar names from `names`, and tick labels shown
/// wherever they fit (egui_plot's default hides labels less than 60 px apart).
pub(super) fn bar_axis<'a>(label: &str, names: Vec<String>) -> egui_plot::AxisHints<'a> {
    egui_plot::AxisHints::new_x()
        .label(label.to_owned())
        .label_spacing(12.0..=24.0)
        .formatter(move |mark, _range| {
            let i = mark.value.round();
            if (mark.value - i).abs() < 1e-6 && i >= 0.0 {
                names.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
}
