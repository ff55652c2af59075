//! Which vision foundation model describes the selected views: [`VfmSpec`], the parameter
//! the pipeline's `ImageBranchParams`, the CLI's `--vfm` and the inspector edit.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `--vfm xfeat|disk|alike|mast3r`; the model file comes from `--vfm-model`.
impl clap::ValueEnum for VfmSpec {
    fn value_variants<'a>() -> &'a [Self] {
        static V: std::sync::LazyLock<[VfmSpec; 4]> = std::sync::LazyLock::new(VfmSpec::all);
        &*V
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.name()))
    }
}

/// Which vision foundation model describes the selected views.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum VfmSpec {
    /// XFeat through ONNX (default `models/xfeat.onnx`): one descriptor grid per view.
    Xfeat {
        #[serde(with = "super::model_path_serde")]
        model: PathBuf,
    },
    /// DISK through ONNX (default `models/disk.onnx`): dense 128-D descriptors at every pixel,
    /// sampled at the lifted pixels.
    Disk {
        #[serde(with = "super::model_path_serde")]
        model: PathBuf,
    },
    /// ALIKE through ONNX (default `models/alike-t.onnx`, 64-D; `models/alike-n.onnx` is 128-D):
    /// dense descriptors at every pixel, sampled at the lifted pixels.
    Alike {
        #[serde(with = "super::model_path_serde")]
        model: PathBuf,
    },
    /// A MASt3R ONNX export (reference §13 signature): descriptors of every ordered
    /// (source view, target view) pair, compared pair-conditioned (reference §8.1).
    Mast3r {
        #[serde(with = "super::model_path_serde")]
        model: PathBuf,
    },
}

impl VfmSpec {
    /// Whether the model describes both scans' views jointly (MASt3R), not one image at a time.
    pub fn is_pair_conditioned(&self) -> bool {
        matches!(self, VfmSpec::Mast3r { .. })
    }

    /// Whether this VFM has a descriptor at every pixel (DISK, ALIKE): the one kind that reads
    /// the image branch's `dense_stride` (`pipeline::ImageBranchParams`).
    pub fn is_dense(&self) -> bool {
        matches!(self, VfmSpec::Disk { .. } | VfmSpec::Alike { .. })
    }

    pub fn model(&self) -> &std::path::Path {
        match self {
            VfmSpec::Xfeat { model }
            | VfmSpec::Disk { model }
            | VfmSpec::Alike { model }
            | VfmSpec::Mast3r { model } => model,
        }
    }

    /// The model file, for the field that edits it.
    pub fn model_mut(&mut self) -> &mut PathBuf {
        match self {
            VfmSpec::Xfeat { model }
            | VfmSpec::Disk { model }
            | VfmSpec::Alike { model }
            | VfmSpec::Mast3r { model } => model,
        }
    }

    /// Every VFM with its default model file (MASt3R has none: no weights ship with cgenreg,
    /// so its path is empty until the user gives an export).
    pub fn all() -> [VfmSpec; 4] {
        [
            VfmSpec::default(),
            VfmSpec::Disk {
                model: super::default_model_path("disk.onnx"),
            },
            VfmSpec::Alike {
                model: super::default_model_path("alike-t.onnx"),
            },
            VfmSpec::Mast3r {
                model: PathBuf::new(),
            },
        ]
    }

    /// The inspector's choice text.
    pub fn label(&self) -> &'static str {
        match self {
            VfmSpec::Xfeat { .. } => "xfeat",
            VfmSpec::Disk { .. } => "disk (dense per pixel)",
            VfmSpec::Alike { .. } => "alike (dense per pixel)",
            VfmSpec::Mast3r { .. } => "mast3r (your ONNX export)",
        }
    }

    pub fn same_kind(&self, other: &VfmSpec) -> bool {
        std::mem::discriminant(self) == std::mem::discriminant(other)
    }

    pub fn name(&self) -> &'static str {
        match self {
            VfmSpec::Xfeat { .. } => "xfeat",
            VfmSpec::Disk { .. } => "disk",
            VfmSpec::Alike { .. } => "alike",
            VfmSpec::Mast3r { .. } => "mast3r",
        }
    }
}

impl Default for VfmSpec {
    fn default() -> Self {
        VfmSpec::Xfeat {
            model: super::default_xfeat_path(),
        }
    }
}
