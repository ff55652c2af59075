//! The 3D panel: source (yellow) and target (blue) clouds drawn by three-d, alignments,
//! correspondence lines, camera frusta, orbit/pan/zoom and picking.

use std::sync::Arc;

use eframe::egui;
use nalgebra::{Isometry3, Matrix4, Point3};
use serde::{Deserialize, Serialize};

use super::colormap::{self, to_color32, HIGHLIGHT_RGB, SOURCE_RGB, TARGET_RGB};
use super::model::{Branch, InspectorModel};
use super::render3d::{self, CloudData, DepthCue, Instance, LineData, SceneFrame};
use super::{MatchColorMode, Shared};
use crate::geometry::knn::KdIndex;

/// three-d's perspective camera driven by its [`three_d::OrbitControl`]. Clouds use OpenCV
/// axes (y down), so "up" is -y.
#[derive(Clone, Debug)]
pub struct SceneCamera {
    pub camera: three_d::Camera,
    pub control: three_d::OrbitControl,
    pub fov_y: f32,
}

impl Default for SceneCamera {
    fn default() -> Self {
        Self::looking_at([0.0, 0.0, 2.0], 4.0, 0.0, 0.35)
    }
}

impl SceneCamera {
    /// Orbiting `target` at `distance`, `yaw` about the up axis, `pitch` above the horizon.
    fn looking_at(target: [f32; 3], distance: f32, yaw: f32, pitch: f32) -> Self {
        let fov_y = 0.9f32;
        let t = three_d::vec3(target[0], target[1], target[2]);
        let (cp, sp) = (pitch.cos(), pitch.sin());
        let dir = three_d::vec3(cp * yaw.sin(), -sp, -cp * yaw.cos());
        let camera = three_d::Camera::new_perspective(
            three_d::Viewport::new_at_origo(1, 1),
            t + dir * distance,
            t,
            three_d::vec3(0.0, -1.0, 0.0),
            three_d::radians(fov_y),
            0.01,
            100.0,
        );
        let mut me = Self {
            camera,
            control: three_d::OrbitControl::new(t, 1e-3, 1e5),
            fov_y,
        };
        me.update_clip_planes();
        me
    }

    /// Frames an axis-aligned box, seen from behind the scan origin (-z) and slightly above.
    pub fn framing(lo: [f32; 3], hi: [f32; 3]) -> Self {
        let c = [
            (lo[0] + hi[0]) / 2.0,
            (lo[1] + hi[1]) / 2.0,
            (lo[2] + hi[2]) / 2.0,
        ];
        let r = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2))
            .sqrt()
            .max(1e-3)
            / 2.0;
        Self::looking_at(c, r / (0.9f32 / 2.0).tan() * 0.8, 0.35, 0.45)
    }

    pub fn distance(&self) -> f32 {
        use three_d::InnerSpace;
        (self.camera.position() - self.control.target).magnitude()
    }

    /// Near and far planes follow the distance (a room and a LiDAR sweep both stay sharp).
    fn update_clip_planes(&mut self) {
        let d = self.distance();
        self.camera.set_perspective_projection(
            three_d::radians(self.fov_y),
            (d * 0.01).max(1e-3),
            d * 20.0 + 10.0,
        );
    }

    fn event(&mut self, e: three_d::Event) {
        self.control.handle_events(&mut self.camera, &mut [e]);
        self.update_clip_planes();
    }

    /// A left drag of (`dx`, `dy`) pixels, through the orbit control.
    pub fn orbit(&mut self, dx: f32, dy: f32) {
        self.event(three_d::Event::MouseMotion {
            button: Some(three_d::MouseButton::Left),
            delta: (dx * 0.8, dy * 0.8),
            position: three_d::PhysicalPoint { x: 0.0, y: 0.0 },
            modifiers: three_d::Modifiers::default(),
            handled: false,
        });
    }

    /// Scroll by `scroll` points (egui's units), through the orbit control.
    pub fn zoom(&mut self, scroll: f32) {
        self.event(three_d::Event::MouseWheel {
            delta: (0.0, scroll * 0.25),
            position: three_d::PhysicalPoint { x: 0.0, y: 0.0 },
            modifiers: three_d::Modifiers::default(),
            handled: false,
        });
    }

    /// Moves the orbit centre in the image plane; `dx`, `dy` in pixels of a view `height`
    /// high (the orbit control has no pan).
    pub fn pan(&mut self, dx: f32, dy: f32, height: f32) {
        let scale = 2.0 * self.distance() * (self.fov_y / 2.0).tan() / height.max(1.0);
        let right = self.camera.right_direction();
        let up = self.camera.up_orthogonal();
        let change = -right * dx * scale + up * dy * scale;
        self.camera.translate(change);
        self.control.target += change;
    }

    /// Projection times view for a `w` x `h` viewport (column-major, OpenGL clip space).
    pub fn view_projection(&mut self, w: f32, h: f32) -> Matrix4<f32> {
        self.camera.set_viewport(three_d::Viewport::new_at_origo(
            w.max(1.0) as u32,
            h.max(1.0) as u32,
        ));
        let m = self.camera.projection() * self.camera.view();
        let a: &[f32; 16] = m.as_ref();
        Matrix4::from_column_slice(a)
    }
}

/// Projects a point with a view-projection matrix into pixel coordinates of a `w` x `h`
/// viewport (origin top-left). None behind the camera.
pub fn project(vp: &Matrix4<f32>, p: [f32; 3], w: f32, h: f32) -> Option<[f32; 2]> {
    let c = vp * nalgebra::Vector4::new(p[0], p[1], p[2], 1.0);
    if c.w <= 1e-6 {
        return None;
    }
    let (x, y) = (c.x / c.w, c.y / c.w);
    Some([(x + 1.0) * 0.5 * w, (1.0 - y) * 0.5 * h])
}

/// Per-point display normals of one cloud (shared with the GL thread).
type DisplayNormals = Arc<Vec<[f32; 3]>>;

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

/// Residuals saturate the colormap at this distance (metres).
pub const RESIDUAL_CAP_M: f32 = 0.1;

/// Persisted options of the 3D panel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct View3dPrefs {
    pub show_initial: bool,
    pub show_estimated: bool,
    pub show_ground_truth: bool,
    pub show_target: bool,
    pub show_lines: bool,
    pub show_frusta: bool,
    pub point_size: f32,
    pub source_mode: CloudColorMode,
    pub target_mode: CloudColorMode,
    pub depth_cue: DepthCue,
    /// Eye-dome lighting strength (1: moderate).
    pub edl_strength: f32,
}

impl Default for View3dPrefs {
    fn default() -> Self {
        Self {
            show_initial: false,
            show_estimated: true,
            show_ground_truth: false,
            show_target: true,
            show_lines: true,
            show_frusta: true,
            point_size: 2.0,
            source_mode: CloudColorMode::Fixed,
            target_mode: CloudColorMode::Fixed,
            depth_cue: DepthCue::None,
            edl_strength: 1.0,
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
}

/// Points drawn per cloud while the camera moves (a uniform subsample; see
/// `render3d::GpuCloud::sync`). Under llvmpipe each point costs about 0.4 µs of CPU, so this
/// keeps orbiting near 30 fps; the full cloud is drawn as soon as the camera stops.
pub const MOVING_POINT_BUDGET: u32 = 50_000;

/// Reuses `prev` when the contents are unchanged, so the GPU buffer is not re-uploaded.
fn keep_or_new(prev: &mut Option<LineData>, pos: Vec<[f32; 3]>, col: Vec<[u8; 4]>) -> LineData {
    if let Some(p) = prev {
        if *p.positions == pos && *p.colors == col {
            return p.clone();
        }
    }
    let l = LineData {
        id: next_id(),
        positions: Arc::new(pos),
        colors: Arc::new(col),
    };
    *prev = Some(l.clone());
    l
}

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

/// Unoriented unit normals for shading (local PCA over the 16 nearest points within four
/// point spacings; zero where degenerate), from the library's normal estimation.
pub fn display_normals(pts: &[[f32; 3]]) -> Vec<[f32; 3]> {
    if pts.len() < 3 {
        return vec![[0.0; 3]; pts.len()];
    }
    let p: Vec<Point3<f32>> = pts.iter().map(|q| point3(*q)).collect();
    let index = KdIndex::new(&p);
    // the spacing: median distance to the nearest other point over a sample
    let step = (p.len() / 256).max(1);
    let mut d: Vec<f32> = p
        .iter()
        .step_by(step)
        .filter_map(|q| index.knn(q, 2).get(1).map(|x| x.1))
        .collect();
    d.sort_by(f32::total_cmp);
    let spacing = d.get(d.len() / 2).copied().unwrap_or(0.01).max(1e-4);
    crate::geometry::normals::estimate_normals(&p, &index, 4.0 * spacing as f64, 16)
        .into_iter()
        .map(|n| [n.x, n.y, n.z])
        .collect()
}

/// Per-point colours of a cloud under a colour mode.
pub fn cloud_colors(model: &InspectorModel, is_source: bool, mode: CloudColorMode) -> Vec<[u8; 4]> {
    let pts = if is_source {
        &model.source
    } else {
        &model.target
    };
    let base = if is_source { SOURCE_RGB } else { TARGET_RGB };
    let dim = |c: [u8; 3]| rgba([c[0] / 3 + 40, c[1] / 3 + 40, c[2] / 3 + 40]);
    match mode {
        CloudColorMode::Fixed => vec![rgba(base); pts.len()],
        CloudColorMode::Visibility => {
            let views = if is_source {
                &model.source_views
            } else {
                &model.target_views
            };
            // Best state over the views: visible beats occluded beats outside.
            let mut state = vec![None::<u8>; pts.len()];
            for v in views.iter().filter(|v| v.point_state.len() == pts.len()) {
                for (s, &x) in state.iter_mut().zip(&v.point_state) {
                    *s = Some(s.map_or(x, |y| y.max(x)));
                }
            }
            state
                .into_iter()
                .map(|s| match s {
                    Some(2) => rgba(VISIBLE_RGB),
                    Some(1) => rgba(OCCLUDED_RGB),
                    Some(_) => dim(base),
                    None => rgba([128, 128, 128]),
                })
                .collect()
        }
        CloudColorMode::FusedScore | CloudColorMode::Branch => {
            let mut out = vec![dim(base); pts.len()];
            for m in &model.matches {
                let i = if is_source { m.src } else { m.tgt };
                if i < out.len() {
                    out[i] = rgba(if mode == CloudColorMode::FusedScore {
                        colormap::turbo(m.score)
                    } else {
                        branch_rgb(m.branch)
                    });
                }
            }
            out
        }
        CloudColorMode::ResidualEstimate | CloudColorMode::ResidualGroundTruth => {
            let t = if mode == CloudColorMode::ResidualEstimate {
                model.estimated
            } else {
                model.ground_truth
            };
            let Some(t) = t else {
                return vec![rgba([128, 128, 128]); pts.len()];
            };
            let (from, to, xf) = if is_source {
                (&model.source, &model.target, t)
            } else {
                (&model.target, &model.source, t.inverse())
            };
            let index = KdIndex::new(&to.iter().map(|p| point3(*p)).collect::<Vec<_>>());
            use rayon::prelude::*;
            from.par_iter()
                .map(|p| {
                    // no point in the other cloud: as far as the colormap goes
                    let d = index
                        .nearest(&point3(apply(&xf, *p)))
                        .map_or(RESIDUAL_CAP_M, |(_, d)| d.min(RESIDUAL_CAP_M));
                    rgba(colormap::turbo(d / RESIDUAL_CAP_M))
                })
                .collect()
        }
    }
}

pub fn branch_rgb(b: Branch) -> [u8; 3] {
    match b {
        Branch::Image => [255, 80, 220],
        Branch::Geometry => [40, 230, 230],
        Branch::Both => [255, 255, 255],
    }
}

/// Colour of a shown match under the chosen colour mode (`rank` is its index in the shown set).
pub fn match_rgb(model: &InspectorModel, idx: usize, rank: usize, mode: MatchColorMode) -> [u8; 3] {
    let m = &model.matches[idx];
    match mode {
        MatchColorMode::Categorical => colormap::categorical(rank),
        MatchColorMode::InlierOutlier => match m.inlier_gt {
            Some(true) => colormap::INLIER_RGB,
            Some(false) => colormap::OUTLIER_RGB,
            None => [160, 160, 160],
        },
        MatchColorMode::Confidence => colormap::turbo(m.score),
    }
}

fn frustum_lines(
    model: &InspectorModel,
    src_xf: &Isometry3<f64>,
    range: f64,
    pos: &mut Vec<[f32; 3]>,
    col: &mut Vec<[u8; 4]>,
) {
    let mut add = |views: &[super::model::ViewImage], xf: &Isometry3<f64>, c: [u8; 3]| {
        for v in views {
            let Some(cam) = &v.camera else { continue };
            let f = cam.camera.frustum(&cam.cloud_from_camera.inverse(), range);
            let w = |p: &Point3<f64>| {
                let q = xf * p;
                [q.x as f32, q.y as f32, q.z as f32]
            };
            let o = w(&f.apex);
            for corner in &f.corners {
                pos.extend_from_slice(&[o, w(corner)]);
            }
            // The border is sampled (curved for f-theta): a closed polyline.
            let n = f.border.len();
            for i in 0..n {
                pos.extend_from_slice(&[w(&f.border[i]), w(&f.border[(i + 1) % n])]);
            }
            col.resize(pos.len(), rgba(c));
        }
    };
    add(&model.source_views, src_xf, [255, 230, 120]);
    add(&model.target_views, &Isometry3::identity(), [140, 190, 255]);
}

/// Frustum depth for display, so frusta scale with the scene (tens of cm in a room, metres
/// around a LiDAR scan): a tenth of the cloud's bounding-box diagonal, 0.2-15 m.
fn frustum_range(cloud: &[[f32; 3]]) -> f64 {
    match super::model::bounds_of(cloud) {
        Some((lo, hi)) => {
            let d = (0..3).map(|i| (hi[i] - lo[i]).powi(2)).sum::<f32>().sqrt() as f64;
            (0.1 * d).clamp(0.2, 15.0)
        }
        None => 0.35,
    }
}

fn point_segment_distance(p: egui::Pos2, a: egui::Pos2, b: egui::Pos2) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_sq().max(1e-6)).clamp(0.0, 1.0);
    (a + ab * t - p).length()
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
}

/// The 3D viewport. `target_override` recolours the target (posterior heat map).
pub fn scene_ui(
    ui: &mut egui::Ui,
    shared: &mut Shared<'_>,
    state: &mut View3dState,
    target_override: Option<TargetOverride>,
) {
    let model = shared.model;
    let gen = shared.model_gen;
    let (rect, response) = ui.allocate_exact_size(
        ui.available_size().max(egui::vec2(64.0, 64.0)),
        egui::Sense::click_and_drag(),
    );
    if state.framed_for != Some(gen) {
        state.camera = match model.bounds() {
            Some((lo, hi)) => SceneCamera::framing(lo, hi),
            None => SceneCamera::default(),
        };
        state.framed_for = Some(gen);
    }
    if state.positions_for != Some(gen) {
        state.source_pos = Arc::new(model.source.clone());
        state.target_pos = Arc::new(model.target.clone());
        state.frustum_range = frustum_range(&model.target);
        state.positions_for = Some(gen);
    }
    let shade_normals = state.prefs.depth_cue == DepthCue::Normals;
    if shade_normals && state.normals.as_ref().is_none_or(|n| n.0 != gen) {
        state.normals = Some((
            gen,
            Arc::new(display_normals(&model.source)),
            Arc::new(display_normals(&model.target)),
        ));
    }

    // Interaction: left drag orbits, right/middle drag or shift-drag pans, scroll zooms,
    // double click resets.
    if response.dragged() {
        let d = response.drag_delta();
        let pan = response.dragged_by(egui::PointerButton::Secondary)
            || response.dragged_by(egui::PointerButton::Middle)
            || ui.input(|i| i.modifiers.shift);
        if pan {
            state.camera.pan(d.x, d.y, rect.height());
        } else {
            state.camera.orbit(d.x, d.y);
        }
    }
    if response.hovered() {
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        if scroll != 0.0 {
            state.camera.zoom(scroll);
        }
    }
    if response.double_clicked() {
        state.framed_for = None;
    }

    let prefs = state.prefs.clone();
    let vp = state.camera.view_projection(rect.width(), rect.height());
    // a hypothesis selected in the hypothesis browser replaces the estimate
    let hyp_pose = shared.ui.hypothesis.as_ref().map(|h| h.pose);
    let src_xf = hyp_pose.unwrap_or_else(|| primary_alignment(model, &prefs));

    // colours, recomputed only when the mode or the model changes
    for (is_src, cache, mode, pos) in [
        (
            true,
            &mut state.source_colors,
            prefs.source_mode,
            &state.source_pos,
        ),
        (
            false,
            &mut state.target_colors,
            prefs.target_mode,
            &state.target_pos,
        ),
    ] {
        let key = (gen, mode, is_src, shade_normals as u64);
        if cache.key != Some(key) {
            let colors = Arc::new(cloud_colors(model, is_src, mode));
            let normals = state.normals.as_ref().filter(|_| shade_normals).map(|n| {
                if is_src {
                    n.1.clone()
                } else {
                    n.2.clone()
                }
            });
            cache.data = Some(CloudData {
                id: next_id(),
                positions: pos.clone(),
                colors,
                normals,
            });
            cache.key = Some(key);
        }
    }
    let (Some(source), Some(mut target)) = (
        state.source_colors.data.clone(),
        state.target_colors.data.clone(),
    ) else {
        return;
    };
    if let Some(o) = target_override {
        target = CloudData {
            id: o.id,
            positions: target.positions.clone(),
            colors: o.colors,
            normals: target.normals.clone(),
        };
    }

    let mut instances = Vec::new();
    let mut add_inst = |on: bool, t: Option<Isometry3<f64>>, tint: [f32; 4]| {
        if let (true, Some(t)) = (on, t) {
            instances.push(Instance {
                model: mat_to_arr(&iso_to_mat(&t)),
                tint,
            });
        }
    };
    add_inst(
        prefs.show_initial,
        Some(model.initial),
        [1.0, 0.55, 0.5, 1.0],
    );
    add_inst(
        prefs.show_ground_truth,
        model.ground_truth,
        [0.55, 1.0, 0.55, 1.0],
    );
    match hyp_pose {
        Some(h) => add_inst(true, Some(h), [0.6, 0.8, 1.0, 1.0]),
        None => add_inst(prefs.show_estimated, model.estimated, [1.0, 1.0, 1.0, 1.0]),
    }

    // correspondence lines (source endpoint under the primary alignment)
    let shown = shared.shown_matches();
    let mut lpos = Vec::new();
    let mut lcol = Vec::new();
    let mut screen_segments = Vec::with_capacity(shown.len());
    for (rank, &mi) in shown.iter().enumerate() {
        let m = &model.matches[mi];
        let (Some(s), Some(t)) = (model.source.get(m.src), model.target.get(m.tgt)) else {
            continue;
        };
        let a = apply(&src_xf, *s);
        if prefs.show_lines {
            lpos.extend_from_slice(&[a, *t]);
            let c = rgba(match_rgb(model, mi, rank, shared.ui.match_mode));
            lcol.extend_from_slice(&[c, c]);
        }
        if let (Some(pa), Some(pb)) = (
            project(&vp, a, rect.width(), rect.height()),
            project(&vp, *t, rect.width(), rect.height()),
        ) {
            screen_segments.push((
                mi,
                rect.min + egui::vec2(pa[0], pa[1]),
                rect.min + egui::vec2(pb[0], pb[1]),
            ));
        }
    }
    let mut fpos = Vec::new();
    let mut fcol = Vec::new();
    if prefs.show_frusta {
        frustum_lines(model, &src_xf, state.frustum_range, &mut fpos, &mut fcol);
    }
    let overlay_lines = keep_or_new(&mut state.overlay, lpos, lcol);
    let scene_lines = keep_or_new(&mut state.frusta, fpos, fcol);
    let view_proj = mat_to_arr(&vp);
    let moving = state.last_view_proj.is_some_and(|last| last != view_proj);
    state.last_view_proj = Some(view_proj);
    if moving {
        // one more frame after the motion stops, drawn in full
        ui.ctx().request_repaint();
    }
    use three_d::Viewer;
    let eye = state.camera.camera.position();
    let frame = SceneFrame {
        source,
        target,
        source_instances: instances,
        show_target: prefs.show_target,
        view_proj,
        eye: [eye.x, eye.y, eye.z],
        near: state.camera.camera.z_near(),
        far: state.camera.camera.z_far(),
        depth_cue: prefs.depth_cue,
        edl_strength: prefs.edl_strength,
        point_budget: moving.then_some(MOVING_POINT_BUDGET),
        overlay_lines,
        scene_lines,
        point_size: prefs.point_size,
        background: [0.07, 0.07, 0.09, 1.0],
    };
    ui.painter()
        .add(render3d::paint_callback(rect, Arc::new(frame)));

    // hover / click on a correspondence line, click on a source point
    if let Some(pos) = response.hover_pos() {
        let best = screen_segments
            .iter()
            .map(|(mi, a, b)| (*mi, point_segment_distance(pos, *a, *b)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((mi, d)) = best {
            if d < 5.0 && prefs.show_lines {
                shared.ui.hovered_match = Some(mi);
            }
        }
    }
    if response.clicked() {
        if let Some(mi) = shared.ui.hovered_match {
            shared.select_match(mi);
        } else if let Some(pos) = response.interact_pointer_pos() {
            if let Some(i) = pick_point(&state.source_pos, &src_xf, &vp, rect, pos, 10.0) {
                shared.select_source_point(i);
            }
        }
    }

    // highlight hovered/selected match and the selected source point on top
    let painter = ui.painter_at(rect);
    for (mi, strong) in [
        (shared.ui.selected_match, true),
        (shared.ui.hovered_match, false),
    ] {
        let Some(mi) = mi else { continue };
        if let Some((_, a, b)) = screen_segments.iter().find(|s| s.0 == mi) {
            let c = to_color32(HIGHLIGHT_RGB);
            painter.line_segment(
                [*a, *b],
                egui::Stroke::new(if strong { 3.0 } else { 2.0 }, c),
            );
            painter.circle_stroke(*a, 5.0, egui::Stroke::new(2.0, to_color32(SOURCE_RGB)));
            painter.circle_stroke(*b, 5.0, egui::Stroke::new(2.0, to_color32(TARGET_RGB)));
        }
    }
    if let Some(i) = shared.ui.selected_source_point {
        if let Some(p) = model.source.get(i) {
            if let Some(s) = project(&vp, apply(&src_xf, *p), rect.width(), rect.height()) {
                painter.circle_stroke(
                    rect.min + egui::vec2(s[0], s[1]),
                    7.0,
                    egui::Stroke::new(2.0, egui::Color32::WHITE),
                );
            }
        }
    }
    let hyp = shared.ui.hypothesis.as_ref();
    legend(&painter, rect, model, &prefs, hyp.map(|h| h.legend_label()));
}

fn legend(
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

/// The source point nearest to `pos` on screen within `radius` pixels.
fn pick_point(
    pts: &[[f32; 3]],
    xf: &Isometry3<f64>,
    vp: &Matrix4<f32>,
    rect: egui::Rect,
    pos: egui::Pos2,
    radius: f32,
) -> Option<usize> {
    let m = vp * iso_to_mat(xf);
    let (w, h) = (rect.width(), rect.height());
    let local = pos - rect.min;
    let mut best: Option<(usize, f32, f32)> = None;
    for (i, p) in pts.iter().enumerate() {
        let c = m * nalgebra::Vector4::new(p[0], p[1], p[2], 1.0);
        if c.w <= 1e-6 {
            continue;
        }
        let x = (c.x / c.w + 1.0) * 0.5 * w;
        let y = (1.0 - c.y / c.w) * 0.5 * h;
        let d2 = (x - local.x).powi(2) + (y - local.y).powi(2);
        if d2 <= radius * radius {
            let z = c.z / c.w;
            // prefer the nearest to the camera among those under the cursor
            if best.is_none_or(|b| z < b.2 - 1e-4 || (d2 < b.1 && (z - b.2).abs() < 1e-4)) {
                best = Some((i, d2, z));
            }
        }
    }
    best.map(|b| b.0)
}

pub fn next_id() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static ID: AtomicU64 = AtomicU64::new(1);
    ID.fetch_add(1, Ordering::Relaxed)
}

/// Full 3D panel: options row then the viewport.
pub fn view3d_panel(ui: &mut egui::Ui, shared: &mut Shared<'_>, state: &mut View3dState) {
    view3d_options(ui, state);
    scene_ui(ui, shared, state, None);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_puts_the_box_centre_in_the_middle_and_inside() {
        let mut cam = SceneCamera::framing([-1.0, -1.0, 1.0], [1.0, 1.0, 3.0]);
        let vp = cam.view_projection(300.0, 200.0);
        let c = project(&vp, [0.0, 0.0, 2.0], 300.0, 200.0).unwrap();
        assert!(
            (c[0] - 150.0).abs() < 1e-2 && (c[1] - 100.0).abs() < 1e-2,
            "{c:?}"
        );
        for corner in [[-1.0, -1.0, 1.0], [1.0, 1.0, 3.0], [1.0, -1.0, 1.0]] {
            let p = project(&vp, corner, 300.0, 200.0).unwrap();
            assert!(
                p[0] > 0.0 && p[0] < 300.0 && p[1] > 0.0 && p[1] < 200.0,
                "{p:?}"
            );
        }
        // -y is up: a point above the centre projects above it on screen
        let above = project(&vp, [0.0, -0.5, 2.0], 300.0, 200.0).unwrap();
        assert!(above[1] < c[1]);
    }

    #[test]
    fn orbit_keeps_the_distance_pan_moves_the_centre_zoom_gets_closer() {
        let mut cam = SceneCamera::default();
        let d0 = cam.distance();
        let c0 = cam.control.target;
        cam.orbit(40.0, 10.0);
        assert!((cam.distance() - d0).abs() < 1e-3 * d0);
        assert_eq!(cam.control.target, c0);
        cam.pan(10.0, 0.0, 100.0);
        assert_ne!(cam.control.target, c0);
        assert!((cam.distance() - d0).abs() < 1e-3 * d0);
        // the orbit centre stays in the middle of the view after a pan
        let t = cam.control.target;
        let vp = cam.view_projection(200.0, 100.0);
        let p = project(&vp, [t.x, t.y, t.z], 200.0, 100.0).unwrap();
        assert!(
            (p[0] - 100.0).abs() < 0.05 && (p[1] - 50.0).abs() < 0.05,
            "{p:?}"
        );
        cam.zoom(100.0);
        assert!(cam.distance() < d0);
    }
}
