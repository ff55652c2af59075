//! The 3D viewport's legend (what each colour is) and its help line.

use eframe::egui;

use super::{CloudColorMode, View3dPrefs, OCCLUDED_RGB, VISIBLE_RGB};
use crate::app::colormap::{quantile_value, to_color32, turbo, INLIER_RGB, OUTLIER_RGB};
use crate::app::model::{Branch, InspectorModel};
use crate::app::state::MatchColorMode;

pub(super) fn legend(
    painter: &egui::Painter,
    rect: egui::Rect,
    model: &InspectorModel,
    p: &View3dPrefs,
    hypothesis: Option<String>,
    match_mode: MatchColorMode,
) {
    let scalar = [p.source_mode, p.target_mode]
        .into_iter()
        .any(super::colors::is_scalar);
    let source_rgb = super::colors::fixed_rgb(true, scalar);
    let target_rgb = super::colors::fixed_rgb(false, scalar);
    let mut rows: Vec<(String, [u8; 3])> = Vec::new();
    let tinted = |t: [f32; 3]| {
        [
            (source_rgb[0] as f32 * t[0]) as u8,
            (source_rgb[1] as f32 * t[1]) as u8,
            (source_rgb[2] as f32 * t[2]) as u8,
        ]
    };
    if let Some(h) = hypothesis {
        rows.push((h, tinted([0.6, 0.8, 1.0])));
    } else if p.show_estimated && model.estimated.is_some() {
        rows.push(("source (estimated)".into(), source_rgb));
    }
    if p.show_ground_truth && model.ground_truth.is_some() {
        rows.push(("source (ground truth)".into(), tinted([0.55, 1.0, 0.55])));
    }
    if p.show_initial {
        rows.push(("source (initial)".into(), tinted([1.0, 0.55, 0.5])));
    }
    if p.show_target {
        rows.push(("target".into(), target_rgb));
    }
    if p.source_mode == CloudColorMode::Visibility || p.target_mode == CloudColorMode::Visibility {
        let cams: Vec<&str> = model
            .source_views
            .iter()
            .chain(&model.target_views)
            .filter_map(|v| v.camera.as_ref().map(|c| c.camera.name()))
            .fold(Vec::new(), |mut a, n| {
                if !a.contains(&n) {
                    a.push(n);
                }
                a
            });
        let cams = if cams.is_empty() {
            "no view cameras".to_string()
        } else {
            format!("{} camera", cams.join(" + "))
        };
        rows.push((format!("visible in a view ({cams})"), VISIBLE_RGB));
        rows.push(("in a view, occluded".into(), OCCLUDED_RGB));
        rows.push(("outside every view: dimmed".into(), [110, 110, 110]));
    }
    if [p.source_mode, p.target_mode].contains(&CloudColorMode::Branch) {
        for b in [Branch::Both, Branch::Geometry, Branch::Image] {
            rows.push((
                format!("matched point, proposed by: {}", b.label()),
                super::colors::branch_rgb(b),
            ));
        }
    }
    if p.show_lines && match_mode == MatchColorMode::InlierOutlier && model.ground_truth.is_some() {
        rows.push((
            format!("match: GT inlier ({})", model.gt_inlier_label()),
            INLIER_RGB,
        ));
        rows.push(("match: GT outlier".into(), OUTLIER_RGB));
    }
    let mut y = rect.top() + 8.0;
    for (text, c) in rows {
        let pos = egui::pos2(rect.left() + 10.0, y);
        painter.circle_filled(pos + egui::vec2(5.0, 7.0), 5.0, to_color32(c));
        painter.text(
            pos + egui::vec2(16.0, 0.0),
            egui::Align2::LEFT_TOP,
            text,
            egui::FontId::proportional(13.0),
            egui::Color32::from_gray(230),
        );
        y += 18.0;
    }
    // colour bars: one per continuous scale in use, with its range and units
    let mut bars: Vec<ColorBar> = Vec::new();
    for (mode, who) in [(p.source_mode, "source"), (p.target_mode, "target")] {
        if let Some(b) = cloud_bar(model, mode, who) {
            if let Some(same) = bars.iter_mut().find(|x| x.title_key == b.title_key) {
                same.title = format!("{} (both clouds)", same.title_key);
            } else {
                bars.push(b);
            }
        }
    }
    if p.show_lines && match_mode == MatchColorMode::Confidence && !model.matches.is_empty() {
        bars.push(confidence_bar(
            model,
            "match lines: fused confidence, rank quantile",
        ));
    }
    let mut top = y + 6.0;
    for b in &bars {
        top = color_bar(painter, egui::pos2(rect.left() + 10.0, top), b) + 10.0;
    }
    painter.text(
        rect.right_bottom() + egui::vec2(-8.0, -6.0),
        egui::Align2::RIGHT_BOTTOM,
        format!(
            "{} + {} points · drag: orbit · right/shift-drag: pan · scroll: zoom · double-click: reset",
            model.source.len(),
            model.target.len()
        ),
        egui::FontId::proportional(11.0),
        egui::Color32::from_gray(160),
    );
}

/// A continuous colour scale from position 0 (bottom of the map) to 1, with labelled ticks.
pub struct ColorBar {
    pub title: String,
    /// The mode's name, to merge the source's and the target's bar.
    title_key: String,
    /// (position in [0, 1] along the map, label).
    pub ticks: Vec<(f32, String)>,
    /// The colour at a position in [0, 1] (turbo unless the scale is diverging).
    pub map: fn(f32) -> [u8; 3],
}

impl ColorBar {
    pub fn new(
        title: impl Into<String>,
        ticks: Vec<(f32, String)>,
        map: fn(f32) -> [u8; 3],
    ) -> Self {
        let title = title.into();
        Self {
            title_key: title.clone(),
            title,
            ticks,
            map,
        }
    }
}

/// The colour bar of a cloud colour mode, None for discrete modes.
pub fn cloud_bar(model: &InspectorModel, mode: CloudColorMode, who: &str) -> Option<ColorBar> {
    let cap_cm = super::residual_cap_m(model) * 100.0;
    let residual = |what: &str| {
        let key =
            format!("residual under the {what}: distance to the nearest point of the other cloud");
        Some(ColorBar {
            title: format!("{key} ({who})"),
            title_key: key,
            ticks: (0..=4)
                .map(|i| {
                    let f = i as f32 / 4.0;
                    let v = f * cap_cm;
                    let l = if i == 4 {
                        format!(">= {v:.1} cm")
                    } else {
                        format!("{v:.1} cm")
                    };
                    (f, l)
                })
                .collect(),
            map: turbo,
        })
    };
    match mode {
        CloudColorMode::ResidualEstimate => residual("estimate"),
        CloudColorMode::ResidualGroundTruth => residual("ground truth"),
        CloudColorMode::FusedScore => {
            let mut b = confidence_bar(model, "matched keypoints: fused score, rank quantile");
            b.title = format!("{} ({who}; other points dimmed)", b.title_key);
            Some(b)
        }
        _ => None,
    }
}

/// The rank-quantile scale of the fused confidence, its ticks labelled with the score at
/// each quantile (unitless, in [0, 1]).
pub fn confidence_bar(model: &InspectorModel, what: &str) -> ColorBar {
    let s: Vec<f32> = model.matches.iter().map(|m| m.score).collect();
    let ticks = [0.0f32, 0.25, 0.5, 0.75, 1.0]
        .into_iter()
        .map(|q| {
            let v = quantile_value(&s, q).unwrap_or(f32::NAN);
            (q, format!("q{:.0}: {}", q * 100.0, score_text(v)))
        })
        .collect();
    ColorBar::new(what, ticks, turbo)
}

/// A score near 1 with enough digits to tell neighbours apart (Noisy-AND saturates).
fn score_text(v: f32) -> String {
    if v > 0.99 && v < 1.0 {
        format!("1 - {:.1e}", 1.0 - v as f64)
    } else {
        format!("{v:.3}")
    }
}

/// Draws `bar` horizontally at `at` (title above, ticks below); returns the bottom.
pub fn color_bar(painter: &egui::Painter, at: egui::Pos2, bar: &ColorBar) -> f32 {
    let (w, h) = (240.0, 12.0);
    let font = egui::FontId::proportional(12.0);
    let text = egui::Color32::from_gray(230);
    painter.text(at, egui::Align2::LEFT_TOP, &bar.title, font.clone(), text);
    let top = at.y + 17.0;
    let n = 64;
    for i in 0..n {
        let x0 = at.x + w * i as f32 / n as f32;
        let x1 = at.x + w * (i + 1) as f32 / n as f32 + 0.5;
        let c = to_color32((bar.map)((i as f32 + 0.5) / n as f32));
        painter.rect_filled(
            egui::Rect::from_min_max(egui::pos2(x0, top), egui::pos2(x1, top + h)),
            0.0,
            c,
        );
    }
    painter.rect_stroke(
        egui::Rect::from_min_size(egui::pos2(at.x, top), egui::vec2(w, h)),
        0.0,
        egui::Stroke::new(1.0, egui::Color32::from_gray(200)),
        egui::StrokeKind::Outside,
    );
    for (k, (f, label)) in bar.ticks.iter().enumerate() {
        let x = at.x + w * f;
        painter.line_segment(
            [egui::pos2(x, top + h), egui::pos2(x, top + h + 4.0)],
            egui::Stroke::new(1.0, text),
        );
        // alternate rows so neighbouring labels never overlap
        let y = top + h + 5.0 + if k % 2 == 1 { 14.0 } else { 0.0 };
        let align = match k {
            0 => egui::Align2::LEFT_TOP,
            _ if k + 1 == bar.ticks.len() => egui::Align2::RIGHT_TOP,
            _ => egui::Align2::CENTER_TOP,
        };
        painter.text(
            egui::pos2(x, y),
            align,
            label,
            egui::FontId::proportional(11.0),
            text,
        );
    }
    top + h + 5.0 + 28.0
}
