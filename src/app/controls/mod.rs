//! Pipeline controls: the side panel's widgets over the pipeline's own [`RegisterParams`]
//! (no UI copy of any setting). A change queues the whole parameter set as one
//! [`Command::ApplySettings`] for the worker ([`crate::app::channel`]).

use std::path::PathBuf;

use eframe::egui;

mod scale;

use super::channel::Command;
use crate::estimate::scale::{
    Metres, Scaled, LIFT_RADIUS_PER_VOXEL, RANSAC_PER_VOXEL, THRESHOLD_PER_VOXEL,
};
use crate::estimate::EstimatorKind;
use crate::features::spinnet::Protocol;
use crate::fusion::{Calibration, FusionMode, Selection};
use crate::pipeline::params::{
    GeoFeatureSource, ImageBranchParams, Preset, RegisterParams, WfmSpec,
};
use crate::vfm::VfmSpec;
use crate::wfm::PromptPreset;
use scale::scale_controls;

/// k of top-k selection when the inspector switches to it (the reference's 8000).
pub const DEFAULT_TOPK: usize = crate::fusion::select::REFERENCE_TOP_K;

/// A combo box over `options`; the current value is the option of the same kind (`same`), so
/// choices that carry data (a temperature, k, a model path) keep the current value's data.
fn choice<T: Clone>(
    ui: &mut egui::Ui,
    label: &str,
    value: &mut T,
    options: impl IntoIterator<Item = T>,
    same: impl Fn(&T, &T) -> bool,
    text: impl Fn(&T) -> &'static str,
) {
    // the label on its own line: beside a wide box in a narrow panel it wrapped one letter per
    // line and moved the controls under the pointer
    let l = ui.label(label);
    let r = egui::ComboBox::from_id_salt(label)
        .selected_text(text(value))
        .width(combo_width(ui))
        .show_ui(ui, |ui| {
            for o in options {
                let selected = same(value, &o);
                if ui.selectable_label(selected, text(&o)).clicked() && !selected {
                    *value = o;
                }
            }
        });
    r.response.labelled_by(l.id);
}

/// A combo box's width in the side panel: the panel's, at most 260 px.
fn combo_width(ui: &egui::Ui) -> f32 {
    (ui.available_width() - 8.0).clamp(80.0, 260.0)
}

fn same_variant<T>(a: &T, b: &T) -> bool {
    std::mem::discriminant(a) == std::mem::discriminant(b)
}

/// The side-panel controls over the pipeline's parameters. `image_off` holds the image
/// branch's parameters while the branch is off (choosing a WFM again restores them).
/// Returns the commands the user's changes produced.
pub fn controls_ui(
    ui: &mut egui::Ui,
    params: &mut RegisterParams,
    image_off: &mut ImageBranchParams,
    scene_specific: &str,
    out: &mut Vec<Command>,
) {
    let before = params.clone();
    // the WFM choice decides whether the image branch runs at all
    let mut backend = params.image.as_ref().map(|ib| ib.backend.clone());
    let image_on = backend.is_some();
    let ib: &mut ImageBranchParams = match params.image.as_mut() {
        Some(ib) => ib,
        None => image_off,
    };
    egui::CollapsingHeader::new("Prompt")
        .default_open(true)
        .show(ui, |ui| prompt_controls(ui, ib, scene_specific));
    egui::CollapsingHeader::new("Image branch")
        .default_open(true)
        .show(ui, |ui| image_branch_controls(ui, ib, &mut backend));
    egui::CollapsingHeader::new("Views")
        .default_open(true)
        .show(ui, |ui| view_controls(ui, ib));
    egui::CollapsingHeader::new("Geometry & evaluation")
        .default_open(true)
        .show(ui, |ui| geometry_controls(ui, params));
    egui::CollapsingHeader::new("Calibration & fusion")
        .default_open(true)
        .show(ui, |ui| fusion_controls(ui, params));
    switch_image_branch(params, image_off, image_on, backend);
    egui::CollapsingHeader::new("Scale & success")
        .default_open(true)
        .show(ui, |ui| scale_controls(ui, params));
    if *params != before {
        out.push(Command::ApplySettings(params.clone()));
    }
}

/// Prompt presets, the shared prefix and the scene description. Edits go to a draft that
/// re-runs nothing until “Apply prompt” (a new prompt means a new generation).
fn prompt_controls(ui: &mut egui::Ui, ib: &mut ImageBranchParams, scene_specific: &str) {
    let id = ui.make_persistent_id("prompt_draft");
    let mut draft: crate::wfm::Prompt = ui
        .data_mut(|d| d.get_temp(id))
        .unwrap_or_else(|| ib.prompt.clone());
    let current = PromptPreset::of_scene(&draft.scene).or_else(|| {
        (!scene_specific.is_empty() && draft.scene.trim() == scene_specific.trim())
            .then_some(PromptPreset::SceneSpecific)
    });
    ui.horizontal_wrapped(|ui| {
        for p in PromptPreset::ALL {
            if ui.selectable_label(current == Some(p), p.label()).clicked() {
                draft.scene = p.scene_text(scene_specific);
            }
        }
    });
    let l = ui.label("Shared prefix");
    ui.add(
        egui::TextEdit::multiline(&mut draft.prefix)
            .desired_rows(2)
            .desired_width(f32::INFINITY),
    )
    .labelled_by(l.id);
    let l = ui.label("Scene description");
    ui.add(
        egui::TextEdit::multiline(&mut draft.scene)
            .desired_rows(3)
            .desired_width(f32::INFINITY),
    )
    .labelled_by(l.id);
    // whitespace at either end of the prompt changes nothing the user means
    let trimmed = crate::wfm::Prompt::new(draft.prefix.trim(), draft.scene.trim());
    if trimmed.text() == ib.prompt.text() {
        ui.data_mut(|d| d.remove::<crate::wfm::Prompt>(id));
        return;
    }
    ui.colored_label(
        STATUS_WARN,
        "prompt edited: nothing re-runs until it is applied",
    );
    let mut keep = true;
    ui.horizontal(|ui| {
        if ui
            .button("Apply prompt")
            .on_hover_text("re-runs the generation and the stages after it")
            .clicked()
        {
            ib.prompt = trimmed.clone();
            keep = false;
        }
        if ui.button("Revert").clicked() {
            keep = false;
        }
    });
    if keep {
        ui.data_mut(|d| d.insert_temp(id, draft));
    } else {
        ui.data_mut(|d| d.remove::<crate::wfm::Prompt>(id));
    }
}

/// The colour of a warning in the controls and the status area.
pub const STATUS_WARN: egui::Color32 = egui::Color32::from_rgb(230, 190, 60);

/// The WFM (None: geometry only) with its folder, spec or command, and the seed.
fn image_branch_controls(
    ui: &mut egui::Ui,
    ib: &mut ImageBranchParams,
    backend: &mut Option<WfmSpec>,
) {
    let options = std::iter::once(None).chain(WfmSpec::all().map(|w| match w {
        // keep the folder, spec or command already given
        w if w.same_kind(&ib.backend) => Some(ib.backend.clone()),
        w => Some(w),
    }));
    choice(
        ui,
        "WFM",
        backend,
        options,
        |a, b| match (a, b) {
            (Some(a), Some(b)) => a.same_kind(b),
            (None, None) => true,
            _ => false,
        },
        |w| w.as_ref().map_or("none (geometry only)", |w| w.label()),
    );
    if let Some(WfmSpec::Cached { dir, spec }) = backend {
        path_field(ui, "Cosmos output folder", dir);
        path_field(ui, "JSONL spec", spec);
    }
    if let Some(WfmSpec::Cosmos { command, .. }) = backend {
        ui.label(format!("command: {}", command.join(" ")));
    }
    ui.horizontal(|ui| {
        let l = ui.label("Seed");
        ui.add(egui::DragValue::new(&mut ib.seed).update_while_editing(false))
            .labelled_by(l.id);
    });
}

/// Most frames per fragment the L slider offers (the command line allows more).
pub const MAX_FRAMES_SLIDER: usize = 200;

/// L, the safeguard margin m and K, each bounded by the others so that no invalid
/// combination can be chosen (m < L, 1 <= K <= L - m), the lift radius, the VFM, its model
/// file and (dense VFMs) the read cell.
fn view_controls(ui: &mut egui::Ui, ib: &mut ImageBranchParams) {
    let max_l = MAX_FRAMES_SLIDER.max(ib.frames_per_fragment);
    ui.add(
        egui::Slider::new(&mut ib.frames_per_fragment, 2..=max_l)
            .update_while_editing(false)
            .logarithmic(true)
            .text("L frames per fragment"),
    )
    .on_hover_text("frames of each scan in the depth video the WFM turns into RGB (the paper: 50)");
    clamp_views(ib);
    let l = ib.frames_per_fragment;
    ui.add(
        egui::Slider::new(&mut ib.margin, 0..=(l - 1).min(10))
            .update_while_editing(false)
            .text("Safeguard margin m (frames)"),
    );
    clamp_views(ib);
    let usable = ib.frames_per_fragment - ib.margin;
    ui.add(
        egui::Slider::new(&mut ib.k, 1..=usable.min(16))
            .update_while_editing(false)
            .text("K views"),
    )
    .on_hover_text(format!("at most L - m = {usable} views per side"));
    virtual_camera_controls(ui, ib);
    // the lift radius is in "Scale & success" (it follows the voxel unless set)
    let options = VfmSpec::all().map(|v| match v {
        v if v.same_kind(&ib.vfm) => ib.vfm.clone(),
        v => v,
    });
    choice(
        ui,
        "VFM",
        &mut ib.vfm,
        options,
        VfmSpec::same_kind,
        VfmSpec::label,
    );
    path_field(ui, "VFM model (ONNX)", ib.vfm.model_mut());
    if ib.vfm.is_dense() {
        ui.add(
            egui::Slider::new(&mut ib.dense_stride, 1..=16)
                .update_while_editing(false)
                .text("Dense read cell (px; 1 = per pixel)"),
        )
        .on_hover_text(
            "1 reads the dense map at the lifted pixel; s > 1 interpolates between the centres \
             of s x s cells",
        );
    }
}

/// How depth frames are made for a scan that is only a point cloud, and where a LiDAR scan's
/// f-theta rig stands (`--virtual-camera`, `--lidar-origin`), with what `auto` does.
fn virtual_camera_controls(ui: &mut egui::Ui, ib: &mut ImageBranchParams) {
    use crate::pipeline::params::{LidarOrigin, VirtualCamera};
    let label = |v: &VirtualCamera| match v {
        VirtualCamera::Auto => "auto (f-theta with intensity, else pinhole)",
        VirtualCamera::Pinhole => "pinhole arc (RGB-D-like clouds)",
        VirtualCamera::Ftheta => "f-theta 360° (LiDAR)",
    };
    let all = [
        VirtualCamera::Auto,
        VirtualCamera::Pinhole,
        VirtualCamera::Ftheta,
    ];
    choice(
        ui,
        "Virtual camera (point clouds only)",
        &mut ib.virtual_camera,
        all,
        |a, b| a == b,
        label,
    );
    if ib.virtual_camera == VirtualCamera::Auto {
        ui.weak("LiDAR scans without intensity (KITTI's xyz .bin) need f-theta");
    }
    if ib.virtual_camera != VirtualCamera::Pinhole {
        choice(
            ui,
            "LiDAR rig position",
            &mut ib.lidar_origin,
            LidarOrigin::ALL,
            |a, b| a == b,
            |o| o.label(),
        );
    }
}

/// Keeps m < L and 1 <= K <= L - m (the view selection's conditions) after L or m moved.
pub fn clamp_views(ib: &mut ImageBranchParams) {
    ib.frames_per_fragment = ib.frames_per_fragment.max(2);
    ib.margin = ib.margin.min(ib.frames_per_fragment - 1);
    ib.k = ib.k.clamp(1, ib.frames_per_fragment - ib.margin);
}

/// The geometric branch's features (FPFH or SpinNet, as `--geo-features`; SpinNet's keypoint
/// count as `--spinnet-keypoints`) and the Noisy-AND prior (the keypoint voxel and the
/// distances are in "Scale & success").
fn geometry_controls(ui: &mut egui::Ui, params: &mut RegisterParams) {
    geo_feature_control(ui, &mut params.geo_features);
    let mut auto = params.fusion.prior.is_none();
    ui.horizontal(|ui| {
        ui.checkbox(&mut auto, "Noisy-AND prior 1/(N·M)");
        if let Some(p) = params.fusion.prior.as_mut() {
            ui.add(
                egui::DragValue::new(p)
                    .update_while_editing(false)
                    .range(1e-12..=0.5)
                    .speed(1e-6)
                    .custom_formatter(|v, _| format!("{v:.2e}")),
            );
        }
    });
    match (auto, params.fusion.prior) {
        (true, Some(_)) => params.fusion.prior = None,
        (false, None) => params.fusion.prior = Some(1e-6),
        _ => {}
    }
    // the keypoint voxel and the inlier threshold are in "Scale & success"
}

/// The features of the geometric branch: FPFH, or SpinNet with one of the authors' two
/// checkpoints (their ONNX exports, `docs/spinnet.md`) at a number of keypoints per scan.
/// Features read from files (`--learned-source`, `--geotransformer-pkl`) are shown, not offered.
fn geo_feature_control(ui: &mut egui::Ui, geo: &mut GeoFeatureSource) {
    let label = |g: &GeoFeatureSource| match g {
        GeoFeatureSource::Fpfh => "FPFH",
        GeoFeatureSource::Spinnet {
            protocol: Protocol::ThreeDMatch,
            ..
        } => "SpinNet (3DMatch checkpoint)",
        GeoFeatureSource::Spinnet {
            protocol: Protocol::Kitti,
            ..
        } => "SpinNet (KITTI checkpoint)",
        GeoFeatureSource::Files { .. } => "learned features from files",
        GeoFeatureSource::GeoTransformerPkl { .. } => "GeoTransformer pair file",
    };
    let options = [
        GeoFeatureSource::Fpfh,
        GeoFeatureSource::spinnet(Protocol::ThreeDMatch),
        GeoFeatureSource::spinnet(Protocol::Kitti),
    ];
    let same = |a: &GeoFeatureSource, b: &GeoFeatureSource| match (a, b) {
        (
            GeoFeatureSource::Spinnet { protocol: p, .. },
            GeoFeatureSource::Spinnet { protocol: q, .. },
        ) => p == q,
        _ => same_variant(a, b),
    };
    choice(ui, "Geometric features", geo, options, same, label);
    if let GeoFeatureSource::Spinnet { keypoints, .. } = geo {
        ui.add(
            egui::Slider::new(keypoints, 16..=5000)
                .update_while_editing(false)
                .logarithmic(true)
                .text("SpinNet keypoints per scan"),
        );
    }
}

/// Each branch's calibration and temperature, the fusion mode, the selection (with top-k)
/// and the estimator: the slider edits `params.fusion.calibration_img` itself.
fn fusion_controls(ui: &mut egui::Ui, params: &mut RegisterParams) {
    for (name, cal) in [
        ("Image", &mut params.fusion.calibration_img),
        ("Geometry", &mut params.fusion.calibration_geo),
    ] {
        let tau = cal.tau();
        choice(
            ui,
            &format!("{name} calibration"),
            cal,
            Calibration::all_with_tau(tau),
            same_variant,
            |c| c.label(),
        );
        ui.add(
            egui::Slider::new(cal.tau_mut(), 0.005..=1.0)
                .update_while_editing(false)
                .logarithmic(true)
                .text(format!("{name} temperature")),
        );
    }
    let mode = &mut params.fusion.mode;
    choice(
        ui,
        "Fusion",
        mode,
        FusionMode::ALL,
        |a, b| a == b,
        |m| m.label(),
    );
    selection_controls(ui, &mut params.fusion.selection);
    let options = EstimatorKind::all().map(|e| match e {
        e if e.same_kind(&params.estimator) => params.estimator.clone(),
        e => e,
    });
    choice(
        ui,
        "Estimator",
        &mut params.estimator,
        options,
        EstimatorKind::same_kind,
        EstimatorKind::label,
    );
}

/// The selection rule, and k for top-k.
fn selection_controls(ui: &mut egui::Ui, selection: &mut Selection) {
    let k = match *selection {
        Selection::TopK(k) => k,
        _ => DEFAULT_TOPK,
    };
    choice(
        ui,
        "Selection",
        selection,
        Selection::all_with_k(k),
        same_variant,
        |s| s.label(),
    );
    if let Selection::TopK(k) = selection {
        ui.add(
            egui::Slider::new(k, 100..=20_000)
                .update_while_editing(false)
                .logarithmic(true)
                .text("top-k"),
        );
    }
}

/// Switches the image branch on or off after the WFM choice, keeping its parameters in
/// `image_off` while it is off.
fn switch_image_branch(
    params: &mut RegisterParams,
    image_off: &mut ImageBranchParams,
    image_on: bool,
    backend: Option<WfmSpec>,
) {
    use crate::fusion::FusionMode;
    match (image_on, backend) {
        (true, Some(b)) => match params.image.as_mut() {
            Some(img) => img.backend = b,
            // not on yet: switch it on with the kept parameters
            None => {
                let mut ib = ImageBranchParams {
                    backend: b,
                    ..image_off.clone()
                };
                clamp_views(&mut ib);
                params.image = Some(ib);
            }
        },
        (true, None) => {
            if let Some(ib) = params.image.take() {
                *image_off = ib;
            }
            // the geometric branch's own defaults, as `register` takes them without --wfm
            if params.fusion.selection == Selection::default_for(true) {
                params.fusion.selection = Selection::default_for(false);
            }
            params.fusion.mode = FusionMode::default_for(false, false);
        }
        (false, Some(b)) => {
            let mut ib = ImageBranchParams {
                backend: b,
                ..image_off.clone()
            };
            clamp_views(&mut ib);
            params.image = Some(ib);
            // the fused pipeline's defaults, as `register --wfm` takes them (the union of both
            // branches' correspondences unless the user picked another mode)
            if params.fusion.selection == Selection::default_for(false) {
                params.fusion.selection = Selection::default_for(true);
            }
            // (Noisy-AND too: the paper's mode, `FusionParams::default()`)
            if params.fusion.mode == FusionMode::default_for(false, false)
                || params.fusion.mode == FusionMode::NoisyAnd
            {
                params.fusion.mode = FusionMode::default_for(true, params.fusion.exact_reference);
            }
        }
        (false, None) => {}
    }
}

/// A path text field that commits on Enter or when it loses focus (not per keystroke, so a
/// half-typed path never re-runs the pipeline).
fn path_field(ui: &mut egui::Ui, label: &str, value: &mut PathBuf) {
    let id = ui.make_persistent_id(("path_field", label));
    let mut buf: String = ui
        .data_mut(|d| d.get_temp::<String>(id))
        .unwrap_or_else(|| super::path_display::shown(value));
    let l = ui.label(label);
    let r = ui
        .add(egui::TextEdit::singleline(&mut buf).desired_width(f32::INFINITY))
        .labelled_by(l.id)
        .on_hover_text(value.display().to_string());
    if r.lost_focus() || (r.has_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter))) {
        // the shown (relative) text unchanged keeps the setting's own path
        if buf != super::path_display::shown(value) {
            *value = super::path_display::typed(&buf);
        }
        ui.data_mut(|d| d.remove::<String>(id));
    } else if r.has_focus() {
        ui.data_mut(|d| d.insert_temp(id, buf));
    } else {
        ui.data_mut(|d| d.remove::<String>(id));
    }
}
