//! The 3D panel: source (yellow) and target (blue) clouds drawn by three-d, alignments,
//! correspondence lines, camera frusta, orbit/pan/zoom and picking.
//!
//! `camera.rs`: the orbit camera and projection; `colors.rs`: per-point and per-match
//! colours; `scene.rs`: the viewport (state sync, input, the frame for the GL thread,
//! picking, highlights); `legend.rs`: the legend; `measure.rs`: the distance tool. This file: the panel's persisted options,
//! its state and the options row.

mod camera;
mod colors;
pub mod legend;
pub mod measure;
mod pick;
mod scene;

use std::sync::Arc;

use eframe::egui;
use nalgebra::{Isometry3, Matrix4, Point3};
use serde::{Deserialize, Serialize};

use super::model::InspectorModel;
use super::render3d::{self, CloudData, DepthCue, LineData, Rasterizer};

pub use camera::{project, SceneCamera};
pub use colors::{branch_rgb, cloud_colors, display_normals, match_rgb};
pub use scene::scene_ui;

use colors::DisplayNormals;

/// How a cloud's points are coloured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
pub enum CloudColorMode {
    Fixed,
    #[value(name = "score")]
    FusedScore,
    ResidualEstimate,
    #[value(name = "residual-gt")]
    ResidualGroundTruth,
    Branch,
    /// Seen by the image branch's K views: visible, occluded inside a view, or outside all.
    Visibility,
}

impl CloudColorMode {
    pub const ALL: [CloudColorMode; 6] = [
        Self::Fixed,
        Self::FusedScore,
        Self::ResidualEstimate,
        Self::ResidualGroundTruth,
        Self::Branch,
        Self::Visibility,
    ];
    pub fn label(self) -> &'static str {
        match self {
            Self::Fixed => "Fixed",
            Self::FusedScore => "Fused score",
            Self::ResidualEstimate => "Residual (estimate)",
            Self::ResidualGroundTruth => "Residual (ground truth)",
            Self::Branch => "Proposing branch",
            Self::Visibility => "Seen by the K views",
        }
    }
}

/// "Seen by the K views": visible in at least one view, inside a view but hidden.
pub const VISIBLE_RGB: [u8; 3] = [90, 235, 110];
pub const OCCLUDED_RGB: [u8; 3] = [235, 90, 70];

/// Residuals saturate the colormap at this distance (metres) when a model names no GT inlier distance.
pub const RESIDUAL_CAP_M: f32 = 0.1;

/// The residual colour scale's top for `model`: the run's GT inlier distance (10 cm at the indoor
/// voxel, 60 cm outdoors), so a good LiDAR result is not all at the top of a 10 cm scale.
pub fn residual_cap_m(model: &InspectorModel) -> f32 {
    let t = model.gt_inlier_m as f32;
    if t.is_finite() && t > 0.0 {
        t
    } else {
        RESIDUAL_CAP_M
    }
}

/// Persisted options of the 3D panel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct View3dPrefs {
    pub show_initial: bool,
    pub show_estimated: bool,
    pub show_ground_truth: bool,
    pub show_target: bool,
    pub show_lines: bool,
    /// Draw the source beside the target (shifted along x by the clouds' size): correct
    /// correspondences are then parallel lines of one length, wrong ones cross them.
    pub side_by_side: bool,
    pub show_frusta: bool,
    pub point_size: f32,
    pub source_mode: CloudColorMode,
    pub target_mode: CloudColorMode,
    pub depth_cue: DepthCue,
    /// Eye-dome lighting strength (1: moderate).
    pub edl_strength: f32,
    /// Who draws the points (CPU splatting under a software GL by default).
    pub rasterizer: Rasterizer,
}

impl Default for View3dPrefs {
    fn default() -> Self {
        Self {
            show_initial: false,
            show_estimated: true,
            show_ground_truth: false,
            show_target: true,
            show_lines: true,
            side_by_side: false,
            show_frusta: true,
            point_size: 2.0,
            source_mode: CloudColorMode::Fixed,
            target_mode: CloudColorMode::Fixed,
            depth_cue: DepthCue::Edl,
            edl_strength: 1.0,
            rasterizer: Rasterizer::Auto,
        }
    }
}

/// Colours a cloud: `Arc`ed so unchanged clouds are not re-uploaded.
#[derive(Default)]
struct ColorCache {
    key: Option<(u64, CloudColorMode, bool, u64)>,
    data: Option<CloudData>,
}

#[derive(Default)]
pub struct View3dState {
    pub prefs: View3dPrefs,
    pub camera: SceneCamera,
    framed_for: Option<u64>,
    positions_for: Option<u64>,
    /// Depth of the drawn view frusta, from the target's extent (set with the positions).
    frustum_range: f64,
    source_pos: Arc<Vec<[f32; 3]>>,
    target_pos: Arc<Vec<[f32; 3]>>,
    /// Display normals of both clouds, estimated when normal shading is first asked for.
    normals: Option<(u64, DisplayNormals, DisplayNormals)>,
    source_colors: ColorCache,
    target_colors: ColorCache,
    /// Last uploaded line sets: the same contents keep their id (no re-upload).
    overlay: Option<LineData>,
    frusta: Option<LineData>,
    /// View-projection of the last frame: a different one means the camera is moving.
    last_view_proj: Option<[f32; 16]>,
    /// (points key, end) of the last frame's draw range: a still view continues from there.
    refined: Option<(u64, u32)>,
    /// Draw every point of a still view in its first frame instead of refining it over
    /// several (headless screenshots, which keep one frame).
    pub complete_frames: bool,
    /// The last frame is not the final one: the camera moved within [`SETTLE`], or a still
    /// view has points left undrawn (more frames follow).
    pub refining: bool,
    /// When the camera last moved: the view counts as moving until [`SETTLE`] after it, so a
    /// drag whose events come slower than frames does not start a refinement between them.
    last_motion: Option<std::time::Instant>,
    /// When the last moving frame was drawn (its interval to the next one is that frame's cost).
    last_moving_frame: Option<std::time::Instant>,
    /// Points per cloud drawn while moving, adapted to [`MOVING_FRAME_TARGET`]; 0 until the
    /// first adaptation (read it through [`View3dState::moving_budget`]).
    moving_budget: u32,
    /// The distance tool (not persisted: its ends are indices into the clouds shown now).
    pub measure: measure::Measure,
    /// The last frame's viewport, view-projection and the source's drawn transform
    /// (side-by-side shift included): where a point is on screen.
    last_frame: Option<(egui::Rect, Matrix4<f32>, Isometry3<f64>)>,
}

impl View3dState {
    /// Points per cloud drawn while the camera moves.
    pub fn moving_budget(&self) -> u32 {
        match self.moving_budget {
            0 => MOVING_POINT_BUDGET,
            b => b,
        }
    }

    /// The 3D viewport's rectangle in the last frame.
    pub fn viewport(&self) -> Option<egui::Rect> {
        self.last_frame.as_ref().map(|f| f.0)
    }

    /// Where a point of either cloud was drawn in the last frame (screen coordinates), if it
    /// was in front of the camera.
    pub fn screen_position(&self, p: measure::Picked) -> Option<egui::Pos2> {
        let (rect, vp, src_xf) = self.last_frame.as_ref()?;
        let (pts, xf) = match p.cloud {
            measure::Cloud::Source => (&self.source_pos, *src_xf),
            measure::Cloud::Target => (&self.target_pos, Isometry3::identity()),
        };
        let s = project(
            vp,
            apply(&xf, *pts.get(p.index)?),
            rect.width(),
            rect.height(),
        )?;
        Some(rect.min + egui::vec2(s[0], s[1]))
    }
}

/// Points drawn per cloud while the camera moves at first (a uniform subsample; see
/// `render3d::GpuCloud::sync`); then adapted between [`MOVING_BUDGET_RANGE`] so that moving
/// frames take [`MOVING_FRAME_TARGET`]. The full cloud is drawn once the camera stops.
pub const MOVING_POINT_BUDGET: u32 = 50_000;

/// Bounds of the adapted moving budget (points per cloud).
pub const MOVING_BUDGET_RANGE: (u32, u32) = (10_000, 300_000);

/// The frame interval the moving budget aims at (30 ms: 33 fps).
pub const MOVING_FRAME_TARGET: std::time::Duration = std::time::Duration::from_millis(30);

/// How long after the last camera motion the view still counts as moving.
pub const SETTLE: std::time::Duration = std::time::Duration::from_millis(150);

/// The next moving budget after a moving frame that took `dt`: proportional to the ratio of
/// the target to `dt` (its fixed point is a frame of exactly the target, whatever the part of
/// the frame that does not scale with points), by at most 0.7x-1.25x per frame. Only
/// consecutive moving frames are measured (they follow each other: a repaint is asked for).
pub fn adapt_moving_budget(budget: u32, dt: std::time::Duration) -> u32 {
    let (lo, hi) = MOVING_BUDGET_RANGE;
    let (t, d) = (MOVING_FRAME_TARGET.as_secs_f64(), dt.as_secs_f64());
    if d <= 0.0 || d.is_nan() {
        return budget.clamp(lo, hi);
    }
    let f = (t / d).clamp(0.7, 1.25);
    ((budget as f64 * f).round() as u32).clamp(lo, hi)
}

/// Points per cloud a still view adds per frame until every point is drawn (progressive
/// refinement: a 300k-point pair is complete two frames after the camera stops, and no
/// frame draws more than this many per cloud).
pub const REFINE_POINTS_PER_FRAME: u32 = 150_000;

/// A colour override for the target cloud (posterior heat map in 3D).
pub struct TargetOverride {
    pub id: u64,
    pub colors: Arc<Vec<[u8; 4]>>,
}

fn iso_to_mat(iso: &Isometry3<f64>) -> Matrix4<f32> {
    iso.to_homogeneous().cast::<f32>()
}

fn mat_to_arr(m: &Matrix4<f32>) -> [f32; 16] {
    let mut a = [0.0; 16];
    a.copy_from_slice(m.as_slice());
    a
}

fn rgba(c: [u8; 3]) -> [u8; 4] {
    [c[0], c[1], c[2], 255]
}

/// The transform the source is shown under for lines and picking: estimated, else ground
/// truth, else initial, following the toggles.
/// The shift that puts the source beside the target (side-by-side view): along x, by half
/// of each cloud's bounding-box diagonal plus a tenth of a gap.
pub fn side_by_side_offset(model: &InspectorModel) -> Isometry3<f64> {
    let diag = |pts: &[[f32; 3]]| {
        crate::app::model::bounds_of(pts).map_or(0.0, |(lo, hi)| {
            let d: f32 = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum();
            d.sqrt() as f64
        })
    };
    let dx = 0.55 * (diag(&model.source) + diag(&model.target));
    Isometry3::translation(dx, 0.0, 0.0)
}

pub fn primary_alignment(model: &InspectorModel, prefs: &View3dPrefs) -> Isometry3<f64> {
    if prefs.show_estimated {
        if let Some(e) = model.estimated {
            return e;
        }
    }
    if prefs.show_ground_truth {
        if let Some(g) = model.ground_truth {
            return g;
        }
    }
    if !(prefs.show_estimated || prefs.show_ground_truth || prefs.show_initial) {
        // no source drawn: lines and markers still sit where the source would be
        return model
            .estimated
            .or(model.ground_truth)
            .unwrap_or(model.initial);
    }
    model.initial
}

pub fn point3(p: [f32; 3]) -> Point3<f32> {
    Point3::new(p[0], p[1], p[2])
}

fn apply(t: &Isometry3<f64>, p: [f32; 3]) -> [f32; 3] {
    let q = t * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    [q.x as f32, q.y as f32, q.z as f32]
}

/// Options row above the 3D view.
pub fn view3d_options(ui: &mut egui::Ui, state: &mut View3dState) {
    let p = &mut state.prefs;
    ui.horizontal_wrapped(|ui| {
        ui.label("Source under:");
        ui.checkbox(&mut p.show_initial, "initial");
        ui.checkbox(&mut p.show_estimated, "estimated");
        ui.checkbox(&mut p.show_ground_truth, "ground truth");
        ui.separator();
        ui.checkbox(&mut p.show_target, "target");
        ui.checkbox(&mut p.show_lines, "lines");
        ui.checkbox(&mut p.side_by_side, "side by side")
            .on_hover_text("source shifted beside the target: inliers are parallel lines");
        ui.checkbox(&mut p.show_frusta, "frusta");
        ui.add(egui::Slider::new(&mut p.point_size, 1.0..=8.0).text("point size"));
    });
    ui.horizontal_wrapped(|ui| {
        egui::ComboBox::from_label("Depth cue")
            .selected_text(p.depth_cue.label())
            .show_ui(ui, |ui| {
                for c in DepthCue::ALL {
                    ui.selectable_value(&mut p.depth_cue, c, c.label());
                }
            });
        if p.depth_cue == DepthCue::Edl {
            ui.add(egui::Slider::new(&mut p.edl_strength, 0.1..=4.0).text("EDL strength"));
        }
        // auto says what it resolved to in the last painted frame, once there is one
        let shown = match (p.rasterizer, render3d::cpu_splatting()) {
            (Rasterizer::Auto, Some(true)) => "auto: CPU splatting",
            (Rasterizer::Auto, Some(false)) => "auto: GL points",
            (r, _) => r.label(),
        };
        egui::ComboBox::from_label("Points drawn by")
            .selected_text(shown)
            .show_ui(ui, |ui| {
                for r in Rasterizer::ALL {
                    ui.selectable_value(&mut p.rasterizer, r, r.label());
                }
            })
            .response
            .on_hover_text(
                "auto: splatted on the CPU under a software GL (llvmpipe), where GL points \
                 cost about 0.4 µs each; GL points on a GPU",
            );
    });
    ui.horizontal_wrapped(|ui| {
        for (name, mode) in [
            ("Source colour", &mut p.source_mode),
            ("Target colour", &mut p.target_mode),
        ] {
            egui::ComboBox::from_label(name)
                .selected_text(mode.label())
                .show_ui(ui, |ui| {
                    for m in CloudColorMode::ALL {
                        ui.selectable_value(mode, m, m.label());
                    }
                });
        }
        if ui.button("Reset camera").clicked() {
            state.framed_for = None;
        }
    });
    ui.horizontal_wrapped(|ui| {
        let m = &mut state.measure;
        let was = m.active;
        ui.checkbox(&mut m.active, "measure distance")
            .on_hover_text(
                "clicks pick two points (source or target); the distance between them is shown \
             in metres, in the target's frame",
            );
        if was != m.active {
            m.clear();
        }
        if m.active {
            match m.picked.len() {
                0 => ui.label("click a first point"),
                1 => ui.label("click a second point"),
                _ => ui.label("a third click starts again"),
            };
            if !m.picked.is_empty() && ui.button("Clear").clicked() {
                m.clear();
            }
        }
    });
}

pub fn next_id() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static ID: AtomicU64 = AtomicU64::new(1);
    ID.fetch_add(1, Ordering::Relaxed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// The budget settles where a frame takes the target, from above and below, for frames
    /// of a fixed part plus a part per point, and it stays in its range.
    #[test]
    fn the_moving_budget_converges_to_the_target_frame_time() {
        let (lo, hi) = MOVING_BUDGET_RANGE;
        for (fixed_ms, ns_per_point) in [(11.0, 250.0), (2.0, 40.0), (20.0, 1000.0)] {
            let cost = |b: u32| {
                Duration::from_secs_f64((fixed_ms + b as f64 * ns_per_point * 1e-6) * 1e-3)
            };
            for start in [lo, MOVING_POINT_BUDGET, hi] {
                let mut b = start;
                for _ in 0..60 {
                    b = adapt_moving_budget(b, cost(b));
                }
                let want = ((30.0 - fixed_ms) * 1e6 / ns_per_point).clamp(lo as f64, hi as f64);
                assert!(
                    (b as f64 - want).abs() <= 0.02 * want + 1.0,
                    "fixed {fixed_ms} ms, {ns_per_point} ns/point, from {start}: {b}, want {want:.0}"
                );
            }
        }
        assert_eq!(adapt_moving_budget(50_000, Duration::from_secs(1)), 35_000);
        assert_eq!(adapt_moving_budget(50_000, Duration::ZERO), 50_000);
        assert_eq!(adapt_moving_budget(1, Duration::from_millis(30)), lo);
    }
}
