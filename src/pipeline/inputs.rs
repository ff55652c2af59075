//! What the in-memory tail computes from, as data: each scan's geometric branch
//! ([`GeoBranch`]), the image branch's per-point descriptors ([`ImageInputs`]), both scans'
//! depth views ([`PairViews`], read once), together [`FusionInputs`]: what a registration keeps
//! for a re-fusion (`RegistrationResult::inputs`).

use crate::camera::visibility::DepthView;
use crate::dataset::{FrameSet, ViewOrigin};
use crate::error::{Error, Result};
use crate::features::Features;
use crate::fusion::cosine_similarity;
use crate::geometry::PointCloud;
use crate::io::depth_png::{read_depth_png, DepthImage};
use crate::matrix::DenseMatrix;
use crate::vfm::pair_similarity::PairPointDescriptors;
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

/// Keypoints and their geometric features for one scan.
#[derive(Clone, Debug)]
pub struct GeoBranch {
    pub keypoints: PointCloud,
    pub features: Features,
    pub label: String,
}

/// Inputs of the in-memory stages (similarity onward): with them, a change of temperature,
/// fusion mode, selection or estimator re-runs only `fuse_and_finish` (the GUI keeps them).
#[derive(Clone, Debug)]
pub struct FusionInputs {
    pub source_geo: GeoBranch,
    pub target_geo: GeoBranch,
    /// The image branch's per-point descriptors; None: geometry only.
    pub image: Option<ImageInputs>,
    /// Label of the image branch, as in `RegistrationResult::image_branch` (fusion mode aside).
    pub image_label: Option<String>,
    /// Both scans' depth frames, for the `visibility` fusion mode (None: geometry only).
    pub views: Option<Arc<PairViews>>,
}

/// Per-point image descriptors, as the image similarity needs them.
#[derive(Clone, Debug)]
pub enum ImageInputs {
    /// One unit descriptor per keypoint and its validity: (source, valid, target, valid).
    PerImage(Features, Vec<bool>, Features, Vec<bool>),
    /// Pair-conditioned descriptors (MASt3R): one per keypoint and partner view.
    PairConditioned(PairPointDescriptors),
}

impl ImageInputs {
    /// Which source / target keypoints have an image descriptor.
    pub fn validity(&self) -> (Vec<bool>, Vec<bool>) {
        match self {
            ImageInputs::PerImage(_, vs, _, vt) => (vs.clone(), vt.clone()),
            ImageInputs::PairConditioned(d) => (
                d.src_view.iter().map(Option::is_some).collect(),
                d.tgt_view.iter().map(Option::is_some).collect(),
            ),
        }
    }

    /// The N x M image similarity with its row / column validity.
    pub fn similarity(&self) -> Result<(DenseMatrix, Vec<bool>, Vec<bool>)> {
        match self {
            ImageInputs::PerImage(fs, vs, ft, vt) => {
                Ok((cosine_similarity(fs, ft)?, vs.clone(), vt.clone()))
            }
            ImageInputs::PairConditioned(d) => d.similarity(),
        }
    }

    /// Row `i` of [`Self::similarity`] (the GUI's posterior inspector), without the matrix.
    pub fn similarity_row(&self, i: usize) -> Vec<f32> {
        match self {
            ImageInputs::PerImage(fs, _, ft, _) => {
                let norm = |v: &[f32]| dot(v, v).sqrt().max(1e-12);
                let a = fs.row(i);
                let na = norm(a);
                (0..ft.len())
                    .map(|j| {
                        let b = ft.row(j);
                        dot(a, b) / (na * norm(b))
                    })
                    .collect()
            }
            ImageInputs::PairConditioned(d) => d.similarity_row(i),
        }
    }
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Where a run keeps decoded depth views between its pairs (the run's memo, which implements
/// it above this file): a scan's views are decoded once per run.
pub trait DepthViewStore: Sync {
    /// The views of `paths`, from the store when they are there and unchanged, else `read`.
    fn depth_views(
        &self,
        paths: &[PathBuf],
        read: &dyn Fn() -> Result<Vec<DepthImage>>,
    ) -> Result<Arc<Vec<DepthImage>>>;
}

/// The depth frames of both scans of a pair (every frame the image branch has: the sensor's, or
/// the virtual frames rendered for a cloud-only scan), read once, on first use.
#[derive(Debug)]
pub struct PairViews {
    source: FrameSet,
    target: FrameSet,
    loaded: OnceLock<std::result::Result<[Arc<Vec<DepthImage>>; 2], String>>,
}

impl PairViews {
    pub fn new(source: FrameSet, target: FrameSet) -> Self {
        PairViews {
            source,
            target,
            loaded: OnceLock::new(),
        }
    }

    /// Read every depth frame now (the virtual frames of a run without a cache live in a
    /// scratch folder only until the run ends).
    pub fn load(&self) -> Result<()> {
        self.depths(None).map(|_| ())
    }

    /// [`Self::load`], each side's frames taken from `store` (the run's memo) when an earlier
    /// pair of the same scan read them (the same files, unchanged), and kept there for the next.
    pub fn load_with(&self, store: &dyn DepthViewStore) -> Result<()> {
        self.depths(Some(store)).map(|_| ())
    }

    fn depths(&self, memo: Option<&dyn DepthViewStore>) -> Result<&[Arc<Vec<DepthImage>>; 2]> {
        // L PNG decodes per side, in parallel (the same images in the same order)
        let decode = |fs: &FrameSet| -> Result<Vec<DepthImage>> {
            use rayon::prelude::*;
            fs.frames
                .par_iter()
                .map(|f| read_depth_png(&f.depth_path))
                .collect()
        };
        let read = |fs: &FrameSet| -> Result<Arc<Vec<DepthImage>>> {
            match memo {
                Some(m) => {
                    let paths: Vec<PathBuf> =
                        fs.frames.iter().map(|f| f.depth_path.clone()).collect();
                    m.depth_views(&paths, &|| decode(fs))
                }
                None => decode(fs).map(Arc::new),
            }
        };
        self.loaded
            .get_or_init(|| {
                let both = || -> Result<[Arc<Vec<DepthImage>>; 2]> {
                    let (s, t) = rayon::join(|| read(&self.source), || read(&self.target));
                    Ok([s?, t?])
                };
                both().map_err(|e| e.to_string())
            })
            .as_ref()
            .map_err(|m| Error::Invalid(format!("fusion visibility: {m}")))
    }

    /// Where the pair's cameras stand ([`pair_view_origin`] of both sides).
    pub fn origin(&self) -> ViewOrigin {
        pair_view_origin(self.source.origin, self.target.origin)
    }

    /// (source views, target views).
    pub fn views(&self) -> Result<[Vec<DepthView<'_>>; 2]> {
        let [sd, td] = self.depths(None)?;
        Ok([side(&self.source, sd), side(&self.target, td)])
    }
}

fn side<'a>(fs: &'a FrameSet, depths: &'a [DepthImage]) -> Vec<DepthView<'a>> {
    fs.frames
        .iter()
        .zip(depths)
        .map(|(f, depth)| DepthView {
            camera: &fs.camera,
            scan_from_camera: f.scan_from_camera,
            depth,
        })
        .collect()
}

/// The views of a pair as the visibility rule sees them: virtual when either side's are.
pub fn pair_view_origin(source: ViewOrigin, target: ViewOrigin) -> ViewOrigin {
    match (source, target) {
        (ViewOrigin::Virtual, _) | (_, ViewOrigin::Virtual) => ViewOrigin::Virtual,
        (ViewOrigin::SensorPosition, _) | (_, ViewOrigin::SensorPosition) => {
            ViewOrigin::SensorPosition
        }
        _ => ViewOrigin::Sensor,
    }
}
