//! The 3D viewport's legend (what each colour is) and its help line.

use eframe::egui;

use super::{CloudColorMode, View3dPrefs, OCCLUDED_RGB, VISIBLE_RGB};
use crate::app::colormap::{to_color32, SOURCE_RGB, TARGET_RGB};
use crate::app::model::InspectorModel;

pub(super) fn legend(
    painter: &egui::Painter,
    rect: egui::Rect,
    model: &InspectorModel,
    p: &View3dPrefs,
    hypothesis: Option<String>,
) {
    let mut rows: Vec<(String, [u8; 3])> = Vec::new();
    let tinted = |t: [f32; 3]| {
        [
            (SOURCE_RGB[0] as f32 * t[0]) as u8,
            (SOURCE_RGB[1] as f32 * t[1]) as u8,
            (SOURCE_RGB[2] as f32 * t[2]) as u8,
        ]
    };
    if let Some(h) = hypothesis {
        rows.push((h, tinted([0.6, 0.8, 1.0])));
    } else if p.show_estimated && model.estimated.is_some() {
        rows.push(("source (estimated)".into(), SOURCE_RGB));
    }
    if p.show_ground_truth && model.ground_truth.is_some() {
        rows.push(("source (ground truth)".into(), tinted([0.55, 1.0, 0.55])));
    }
    if p.show_initial {
        rows.push(("source (initial)".into(), tinted([1.0, 0.55, 0.5])));
    }
    if p.show_target {
        rows.push(("target".into(), TARGET_RGB));
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
