//! The 3D viewport: keeps the panel's state in step with the model, turns pointer input into
//! camera motion, builds the frame the GL thread draws ([`SceneFrame`]), and handles picking
//! and the highlights drawn on top.

use std::sync::Arc;

use eframe::egui;
use nalgebra::{Isometry3, Matrix4, Point3};

use super::colors::{cloud_colors, display_normals, match_rgb};
use super::legend::legend;
use super::pick::{hover_readout, pointer_picking, readout_box};
use super::{
    adapt_moving_budget, apply, iso_to_mat, mat_to_arr, next_id, primary_alignment, project, rgba,
    SceneCamera, TargetOverride, View3dPrefs, View3dState, REFINE_POINTS_PER_FRAME, SETTLE,
};
use crate::app::colormap::{to_color32, HIGHLIGHT_RGB, SOURCE_RGB, TARGET_RGB};
use crate::app::model::{bounds_of, InspectorModel, ViewImage};
use crate::app::render3d::{self, CloudData, DepthCue, Instance, LineData, SceneFrame};
use crate::app::state::Shared;

/// A drawn correspondence on screen: (match index, source end, target end).
pub(super) type ScreenSegment = (usize, egui::Pos2, egui::Pos2);

/// The 3D viewport. `target_override` recolours the target (posterior heat map).
pub fn scene_ui(
    ui: &mut egui::Ui,
    shared: &mut Shared<'_>,
    state: &mut View3dState,
    target_override: Option<TargetOverride>,
) {
    let model = shared.model;
    let (rect, response) = ui.allocate_exact_size(
        ui.available_size().max(egui::vec2(64.0, 64.0)),
        egui::Sense::click_and_drag(),
    );
    sync_with_model(state, model, shared.scene_gen);
    camera_input(ui, &response, rect, state);

    let prefs = state.prefs.clone();
    let vp = state.camera.view_projection(rect.width(), rect.height());
    // a hypothesis selected in the hypothesis browser replaces the estimate
    let hyp_pose = shared.ui.hypothesis.as_ref().map(|h| h.pose);
    let offset = if prefs.side_by_side {
        super::side_by_side_offset(model)
    } else {
        Isometry3::identity()
    };
    let pose = hyp_pose.unwrap_or_else(|| primary_alignment(model, &prefs));
    let src_xf = offset * pose;

    update_colors(state, model, shared.model_gen);
    let Some((source, target)) = clouds(state, target_override) else {
        return;
    };
    let (lpos, lcol, segments) = correspondence_lines(shared, &src_xf, &vp, rect, prefs.show_lines);
    let mut fpos = Vec::new();
    let mut fcol = Vec::new();
    if prefs.show_frusta {
        frustum_lines(model, &src_xf, state.frustum_range, &mut fpos, &mut fcol);
    }
    let overlay_lines = keep_or_new(&mut state.overlay, lpos, lcol);
    let scene_lines = keep_or_new(&mut state.frusta, fpos, fcol);
    let view_proj = mat_to_arr(&vp);
    let moving = motion(state, view_proj);
    use three_d::Viewer;
    let eye = state.camera.camera.position();
    let mut frame = SceneFrame {
        source,
        target,
        source_instances: instances(model, &prefs, hyp_pose, &offset),
        show_target: prefs.show_target,
        view_proj,
        eye: [eye.x, eye.y, eye.z],
        near: state.camera.camera.z_near(),
        far: state.camera.camera.z_far(),
        depth_cue: prefs.depth_cue,
        rasterizer: prefs.rasterizer,
        edl_strength: prefs.edl_strength,
        draw_range: (0, 0),
        keep: true,
        overlay_lines,
        scene_lines,
        point_size: prefs.point_size,
        background: [0.07, 0.07, 0.09, 1.0],
    };
    let (range, direct) = draw_range(state, &frame, moving);
    frame.draw_range = range;
    frame.keep = !direct;
    state.refining = direct || range.1 < frame.max_points();
    if state.refining {
        ui.ctx().request_repaint();
    }
    ui.painter()
        .add(render3d::paint_callback(rect, Arc::new(frame)));

    state.last_frame = Some((rect, vp, src_xf));
    pointer_picking(&response, shared, state, &segments, &src_xf, &vp, rect);
    let painter = ui.painter_at(rect);
    highlights(&painter, shared, &segments, &src_xf, &vp, rect);
    draw_measurement(&painter, rect, model, state, &pose);
    if let Some(pos) = response.hover_pos() {
        let text = hover_readout(shared, state, &src_xf, &vp, rect, pos);
        if let Some(text) = text {
            readout_box(&painter, pos, rect, &text);
        }
    }
    let hyp = shared.ui.hypothesis.as_ref();
    legend(
        &painter,
        rect,
        model,
        &prefs,
        hyp.map(|h| h.legend_label()),
        shared.ui.match_mode,
    );
}

/// Which points of each cloud this frame draws, and whether straight to the screen (a
/// preview) rather than into the kept still view: the moving budget afresh while the camera
/// moves, and once when a still view's content changes (a re-fusion moved the pose or the
/// colours: the new alignment shows at once, as while orbiting); for a still view, the next
/// [`REFINE_POINTS_PER_FRAME`] after what the last frame of the same view drew (everything at
/// once with `complete_frames`), nothing new once complete.
fn draw_range(state: &mut View3dState, frame: &SceneFrame, moving: bool) -> ((u32, u32), bool) {
    let n = frame.max_points();
    let preview = |state: &mut View3dState| {
        // a still view starts afresh after it
        state.refined = None;
        ((0, state.moving_budget().min(n)), true)
    };
    if moving {
        return preview(state);
    }
    // CPU splatting draws a whole still view in about the time of a moving frame
    let whole = state.complete_frames || render3d::cpu_splatting() == Some(true);
    let key = frame.points_key();
    let start = match state.refined {
        Some((k, end)) if k == key => end,
        Some(_) if !whole && n > state.moving_budget() => return preview(state),
        _ => 0,
    };
    let step = if whole { n } else { REFINE_POINTS_PER_FRAME };
    let range = (start, start.saturating_add(step).min(n));
    state.refined = Some((key, range.1));
    (range, false)
}

/// Whether this frame counts as moving: the camera changed since the last frame, or within
/// [`SETTLE`] before it (with `complete_frames`, headless: only the former). Moving frames
/// follow each other (`scene_ui` asks for a repaint while `refining`), and the moving budget
/// adapts to their interval.
fn motion(state: &mut View3dState, view_proj: [f32; 16]) -> bool {
    let now = std::time::Instant::now();
    let changed = state.last_view_proj.is_some_and(|last| last != view_proj);
    if changed {
        state.last_motion = Some(now);
    }
    state.last_view_proj = Some(view_proj);
    let settling = state
        .last_motion
        .is_some_and(|t| now.duration_since(t) < SETTLE);
    let moving = changed || (settling && !state.complete_frames);
    if moving {
        if let Some(t) = state.last_moving_frame {
            state.moving_budget = adapt_moving_budget(state.moving_budget(), now.duration_since(t));
        }
        state.last_moving_frame = Some(now);
    } else {
        state.last_moving_frame = None;
    }
    moving
}

/// Frames the camera on new clouds, and keeps the positions (and, for normal shading, the
/// display normals) of the clouds with scene generation `gen` (a re-fusion of the same pair
/// keeps both, and the camera where the user left it).
fn sync_with_model(state: &mut View3dState, model: &InspectorModel, gen: u64) {
    // framed again when the side-by-side layout is switched (the source moves aside)
    let framing = gen ^ state.prefs.side_by_side as u64;
    if state.framed_for != Some(framing) {
        let bounds = model.bounds().map(|(lo, mut hi)| {
            if state.prefs.side_by_side {
                hi[0] += super::side_by_side_offset(model).translation.x as f32;
            }
            (lo, hi)
        });
        state.camera = match bounds {
            Some((lo, hi)) => SceneCamera::framing(lo, hi),
            None => SceneCamera::default(),
        };
        state.framed_for = Some(framing);
    }
    if state.positions_for != Some(gen) {
        state.source_pos = Arc::new(model.source.clone());
        state.target_pos = Arc::new(model.target.clone());
        state.frustum_range = frustum_range(&model.target);
        state.positions_for = Some(gen);
        // the picked indices named points of the clouds shown before
        state.measure.clear();
    }
    let shade_normals = state.prefs.depth_cue == DepthCue::Normals;
    if shade_normals && state.normals.as_ref().is_none_or(|n| n.0 != gen) {
        state.normals = Some((
            gen,
            Arc::new(display_normals(&model.source)),
            Arc::new(display_normals(&model.target)),
        ));
    }
}

/// Left drag orbits, right/middle drag or shift-drag pans, scroll zooms, double click resets.
fn camera_input(
    ui: &egui::Ui,
    response: &egui::Response,
    rect: egui::Rect,
    state: &mut View3dState,
) {
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
}

/// Recomputes a cloud's colours only when its mode, the model or the normal shading changes;
/// keeps the uploaded cloud when they come out the same.
fn update_colors(state: &mut View3dState, model: &InspectorModel, gen: u64) {
    let shade_normals = state.prefs.depth_cue == DepthCue::Normals;
    let (source_mode, target_mode) = (state.prefs.source_mode, state.prefs.target_mode);
    for (is_src, cache, mode, pos) in [
        (
            true,
            &mut state.source_colors,
            source_mode,
            &state.source_pos,
        ),
        (
            false,
            &mut state.target_colors,
            target_mode,
            &state.target_pos,
        ),
    ] {
        let other = if is_src { target_mode } else { source_mode };
        let other_scalar = super::colors::is_scalar(other);
        let key = (
            gen,
            mode,
            is_src,
            shade_normals as u64 | (other_scalar as u64) << 1,
        );
        if cache.key != Some(key) {
            let colors = Arc::new(cloud_colors(model, is_src, mode, other_scalar));
            let normals = state.normals.as_ref().filter(|_| shade_normals).map(|n| {
                if is_src {
                    n.1.clone()
                } else {
                    n.2.clone()
                }
            });
            cache.key = Some(key);
            // a new model with the same points and colours (a re-fusion that kept them) keeps
            // the uploaded cloud, and with it the drawn view
            if cache.data.as_ref().is_some_and(|d| {
                Arc::ptr_eq(&d.positions, pos)
                    && d.colors == colors
                    && match (&d.normals, &normals) {
                        (Some(a), Some(b)) => Arc::ptr_eq(a, b),
                        (a, b) => a.is_none() && b.is_none(),
                    }
            }) {
                continue;
            }
            cache.data = Some(CloudData {
                id: next_id(),
                positions: pos.clone(),
                colors,
                normals,
            });
        }
    }
}

/// The source and target clouds to draw, the target recoloured by `target_override`.
fn clouds(
    state: &View3dState,
    target_override: Option<TargetOverride>,
) -> Option<(CloudData, CloudData)> {
    let source = state.source_colors.data.clone()?;
    let mut target = state.target_colors.data.clone()?;
    if let Some(o) = target_override {
        target = CloudData {
            id: o.id,
            positions: target.positions.clone(),
            colors: o.colors,
            normals: target.normals.clone(),
        };
    }
    Some((source, target))
}

/// The source drawn once per alignment shown: initial, ground truth, and the estimate (or
/// the hypothesis chosen in the hypothesis browser), each with its tint.
fn instances(
    model: &InspectorModel,
    prefs: &View3dPrefs,
    hyp_pose: Option<Isometry3<f64>>,
    offset: &Isometry3<f64>,
) -> Vec<Instance> {
    let mut instances = Vec::new();
    let mut add_inst = |on: bool, t: Option<Isometry3<f64>>, tint: [f32; 4]| {
        if let (true, Some(t)) = (on, t) {
            instances.push(Instance {
                model: mat_to_arr(&iso_to_mat(&(offset * t))),
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
    instances
}

/// Correspondence lines (source endpoint under `src_xf`): their vertices and colours when
/// `show_lines`, and every shown match's segment on screen (for hovering and highlights).
fn correspondence_lines(
    shared: &Shared<'_>,
    src_xf: &Isometry3<f64>,
    vp: &Matrix4<f32>,
    rect: egui::Rect,
    show_lines: bool,
) -> (Vec<[f32; 3]>, Vec<[u8; 4]>, Vec<ScreenSegment>) {
    let model = shared.model;
    let shown = shared.shown_matches();
    let quantiles = model.score_quantiles();
    let mut lpos = Vec::new();
    let mut lcol = Vec::new();
    let mut screen_segments = Vec::with_capacity(shown.len());
    for (rank, &mi) in shown.iter().enumerate() {
        let m = &model.matches[mi];
        let (Some(s), Some(t)) = (model.source.get(m.src), model.target.get(m.tgt)) else {
            continue;
        };
        let a = apply(src_xf, *s);
        if show_lines {
            lpos.extend_from_slice(&[a, *t]);
            let c = rgba(match_rgb(model, mi, rank, shared.ui.match_mode, &quantiles));
            lcol.extend_from_slice(&[c, c]);
        }
        if let (Some(pa), Some(pb)) = (
            project(vp, a, rect.width(), rect.height()),
            project(vp, *t, rect.width(), rect.height()),
        ) {
            screen_segments.push((
                mi,
                rect.min + egui::vec2(pa[0], pa[1]),
                rect.min + egui::vec2(pb[0], pb[1]),
            ));
        }
    }
    (lpos, lcol, screen_segments)
}

/// The hovered and selected match and the selected source point, drawn on top.
fn highlights(
    painter: &egui::Painter,
    shared: &Shared<'_>,
    segments: &[ScreenSegment],
    src_xf: &Isometry3<f64>,
    vp: &Matrix4<f32>,
    rect: egui::Rect,
) {
    for (mi, strong) in [
        (shared.ui.selected_match, true),
        (shared.ui.hovered_match, false),
    ] {
        let Some(mi) = mi else { continue };
        if let Some((_, a, b)) = segments.iter().find(|s| s.0 == mi) {
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
        if let Some(p) = shared.model.source.get(i) {
            if let Some(s) = project(vp, apply(src_xf, *p), rect.width(), rect.height()) {
                painter.circle_stroke(
                    rect.min + egui::vec2(s[0], s[1]),
                    7.0,
                    egui::Stroke::new(2.0, egui::Color32::WHITE),
                );
            }
        }
    }
}

/// The distance tool's ends (ringed), the segment between them and its readout beside it.
/// `pose`: where the source is drawn (without the side-by-side shift), so a source-target
/// distance is the residual the picture shows.
fn draw_measurement(
    painter: &egui::Painter,
    rect: egui::Rect,
    model: &InspectorModel,
    state: &View3dState,
    pose: &Isometry3<f64>,
) {
    use super::measure::{measurement, Cloud};
    if !state.measure.active {
        return;
    }
    let ring = |c: Cloud| match c {
        Cloud::Source => to_color32(SOURCE_RGB),
        Cloud::Target => to_color32(TARGET_RGB),
    };
    let ends: Vec<_> = state
        .measure
        .picked
        .iter()
        .filter_map(|p| Some((*p, state.screen_position(*p)?)))
        .collect();
    for (p, at) in &ends {
        painter.circle_filled(*at, 4.0, egui::Color32::WHITE);
        painter.circle_stroke(*at, 7.0, egui::Stroke::new(2.0, ring(p.cloud)));
    }
    if let [(_, a), (_, b)] = ends.as_slice() {
        painter.line_segment([*a, *b], egui::Stroke::new(2.0, egui::Color32::WHITE));
    }
    if let Some(m) = measurement(model, pose, &state.measure) {
        let at = match ends.as_slice() {
            [(_, a), (_, b)] => egui::pos2((a.x + b.x) / 2.0, (a.y + b.y) / 2.0),
            _ => rect.center(),
        };
        super::pick::readout_box(painter, at, rect, &m.text("drawn pose"));
    }
}

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

fn frustum_lines(
    model: &InspectorModel,
    src_xf: &Isometry3<f64>,
    range: f64,
    pos: &mut Vec<[f32; 3]>,
    col: &mut Vec<[u8; 4]>,
) {
    let mut add = |views: &[ViewImage], xf: &Isometry3<f64>, c: [u8; 3]| {
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
    match bounds_of(cloud) {
        Some((lo, hi)) => {
            let d = (0..3).map(|i| (hi[i] - lo[i]).powi(2)).sum::<f32>().sqrt() as f64;
            (0.1 * d).clamp(0.2, 15.0)
        }
        None => 0.35,
    }
}
