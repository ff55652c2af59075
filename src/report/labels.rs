//! How reports name a run's settings: one short label per setting, from the parameter types
//! (never from a run file's raw JSON), shared by `cgenreg table`, `cgenreg diff` and the
//! inspector's Compare tab. The inspector's controls use the types' own longer `label()`s.

use crate::fusion::{Calibration, FusionMode, Selection};
use crate::pipeline::params::{GeoFeatureSource, ImageBranchParams, RegisterParams, WfmSpec};
use crate::vfm::VfmSpec;

/// "FPFH", "SpinNet 3dmatch (128 keypoints)", ...
pub fn geo(g: &GeoFeatureSource) -> String {
    match g {
        GeoFeatureSource::Fpfh => "FPFH".to_string(),
        GeoFeatureSource::Files { .. } => "learned features (files)".to_string(),
        GeoFeatureSource::GeoTransformerPkl { .. } => "GeoTransformer pkl".to_string(),
        GeoFeatureSource::Spinnet {
            protocol,
            keypoints,
            ..
        } => format!("SpinNet {} ({keypoints} keypoints)", protocol.name()),
    }
}

/// Where the image branch's frames came from.
pub fn wfm(w: &WfmSpec) -> &'static str {
    match w {
        WfmSpec::Oracle => "oracle RGB",
        WfmSpec::Builtin => "built-in shading (not a WFM)",
        WfmSpec::Cached { .. } => "cached Cosmos output",
        WfmSpec::Cosmos { .. } => "Cosmos-Transfer1",
    }
}

/// The VFM and, for the dense ones, how their maps were read: "XFeat", "ALIKE (per pixel)",
/// "DISK (4-px cells)".
pub fn vfm(ib: &ImageBranchParams) -> String {
    let name = match ib.vfm {
        VfmSpec::Xfeat { .. } => "XFeat",
        VfmSpec::Disk { .. } => "DISK",
        VfmSpec::Alike { .. } => "ALIKE",
        VfmSpec::Mast3r { .. } => "MASt3R (user's ONNX export)",
    };
    match (&ib.vfm, ib.dense_stride) {
        (VfmSpec::Disk { .. } | VfmSpec::Alike { .. }, 1) => format!("{name} (per pixel)"),
        (VfmSpec::Disk { .. } | VfmSpec::Alike { .. }, c) => format!("{name} ({c}-px cells)"),
        _ => name.to_string(),
    }
}

/// A fusion mode as tables name it.
pub fn fusion_mode(m: FusionMode) -> &'static str {
    match m {
        FusionMode::NoisyAnd => "Noisy-AND",
        FusionMode::NoisyOr => "Noisy-OR",
        FusionMode::Concat => "Concat.",
        FusionMode::ImageOnly => "image only",
        FusionMode::GeometryOnly => "geometry only",
        FusionMode::Union => "union",
        FusionMode::Visibility => "visibility",
    }
}

/// The fusion a run used ("geometry only" without the image branch).
pub fn fusion(p: &RegisterParams) -> &'static str {
    match &p.image {
        None => "geometry only",
        Some(_) => fusion_mode(p.fusion.mode),
    }
}

/// "mutual NN", "NN", "top-8000".
pub fn selection(s: Selection) -> String {
    match s {
        Selection::MutualNn => "mutual NN".to_string(),
        Selection::RowNn => "NN".to_string(),
        Selection::TopK(k) => format!("top-{k}"),
    }
}

/// The calibration of the branches a run uses, with its temperatures (image / geometric when
/// both are fused) and the Noisy-AND prior when it is not the default 1/(NM): "row τ 0.1/0.1".
pub fn calibration(p: &RegisterParams) -> String {
    let cal = |c: &Calibration| {
        let (kind, tau) = match c {
            Calibration::RowSoftmax { tau } => ("row", tau),
            Calibration::DualSoftmax { tau } => ("dual", tau),
        };
        (kind, format!("{}", (f64::from(*tau) * 1e4).round() / 1e4))
    };
    let (ki, ti) = cal(&p.fusion.calibration_img);
    let (kg, tg) = cal(&p.fusion.calibration_geo);
    let mut s = match (p.image.is_some(), p.fusion.mode) {
        (false, _) | (true, FusionMode::GeometryOnly) | (true, FusionMode::Concat) => {
            format!("{kg} τ {tg}")
        }
        (true, FusionMode::ImageOnly) => format!("{ki} τ {ti}"),
        _ if ki == kg => format!("{ki} τ {ti}/{tg}"),
        _ => format!("{ki} τ {ti} / {kg} τ {tg}"),
    };
    if let Some(prior) = p.fusion.prior {
        s.push_str(&format!(", π {prior:e}"));
    }
    s
}

/// The scale search, when there is one: "scales 0.3/0.6/1.2 m".
pub fn scales(p: &RegisterParams) -> Option<String> {
    (p.scales > 1).then(|| {
        let v: Vec<String> = crate::pipeline::scales::voxels(p)
            .iter()
            .map(|v| format!("{}", (v * 1000.0).round() / 1000.0))
            .collect();
        format!("scales {} m", v.join("/"))
    })
}
