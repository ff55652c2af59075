//! Vision foundation models (VFM): dense image descriptors from ONNX models, and lifting of
//! image pixels to the 3-D points of the geometric branch.
//!
//! Two kinds of model:
//! - [`PerImageModel`]: one image in, one descriptor grid out (XFeat, the default, on an H/8
//!   grid; DISK and ALIKE, [`dense`], at every pixel, sampled at given pixels by
//!   [`PerImageModel::describe_at`] so that no full-resolution map outlives its image).
//! - [`PairModel`]: two images in, one descriptor grid per image, each conditioned on the other
//!   (MASt3R as in the reference, §6). [`describe_all_pairs`] runs all K² ordered pairs,
//!   src-major: pair `k = s·K + t` is (src view s, tgt view t).
//!
//! Descriptor grids are tied to the image they came from by [`DenseDescriptors::stride_x`] /
//! `stride_y` (image pixels per grid cell): [`DenseDescriptors::sample`] maps a pixel of the
//! original image to a descriptor by bilinear interpolation with half-pixel centres, the mapping
//! of `F.interpolate(mode="bilinear", align_corners=False)` the reference uses to upsample
//! MASt3R descriptors to 704×960.
//!
//! ONNX models run through `ort` (cargo feature `onnx`): the native ONNX Runtime library when
//! one is found at run time, the pure-Rust tract backend otherwise; [`backend_name`] says which.

#[cfg(feature = "onnx")]
pub mod dense;
pub mod lift;
#[cfg(feature = "onnx")]
pub mod mast3r;
pub mod pair_similarity;
#[cfg(feature = "onnx")]
#[cfg(feature = "onnx")]
pub mod xfeat;

pub mod preprocess;
pub mod spec;

pub use spec::VfmSpec;

use crate::error::{Error, Result};
use image::RgbImage;

/// A dense grid of descriptors, row-major: cell (x, y) is `data[(y * width + x) * dim ..][..dim]`.
#[derive(Clone, Debug, PartialEq)]
pub struct DenseDescriptors {
    /// Grid size in cells.
    pub width: u32,
    pub height: u32,
    pub dim: usize,
    pub data: Vec<f32>,
    /// Original-image pixels per grid cell along x and y (8 for XFeat at a multiple-of-32 size;
    /// 960/512 and 704/375 for MASt3R descriptors of a 960×704 frame).
    pub stride_x: f32,
    pub stride_y: f32,
}

impl DenseDescriptors {
    /// A grid with checked sizes.
    pub fn new(
        width: u32,
        height: u32,
        dim: usize,
        data: Vec<f32>,
        stride_x: f32,
        stride_y: f32,
    ) -> Result<Self> {
        let n = width as usize * height as usize * dim;
        if data.len() != n || !(stride_x > 0.0 && stride_y > 0.0) {
            return Err(Error::Shape(format!(
                "descriptor grid {width}x{height}x{dim} needs {n} values and positive strides, got {} values, strides {stride_x}/{stride_y}",
                data.len()
            )));
        }
        Ok(DenseDescriptors {
            width,
            height,
            dim,
            data,
            stride_x,
            stride_y,
        })
    }

    /// The descriptor of grid cell (x, y).
    pub fn cell(&self, x: u32, y: u32) -> &[f32] {
        let i = (y as usize * self.width as usize + x as usize) * self.dim;
        &self.data[i..i + self.dim]
    }

    /// Size in pixels of the image the grid covers (may be fractional after a resize).
    pub fn image_size(&self) -> (f32, f32) {
        (
            self.width as f32 * self.stride_x,
            self.height as f32 * self.stride_y,
        )
    }

    /// The descriptor of original-image pixel (u, v) (column, row; the pixel's centre is at
    /// u + 0.5). Bilinear with half-pixel centres and edge clamping, as torch's
    /// `interpolate(bilinear, align_corners=False)`. Not re-normalised.
    pub fn sample(&self, u: f32, v: f32) -> Vec<f32> {
        let mut out = vec![0.0; self.dim];
        self.sample_into(u, v, &mut out);
        out
    }

    /// Unit descriptors at `pixels` (bilinear as [`Self::sample_into`], then L2-normalised; a
    /// descriptor of norm < 1e-12 stays as sampled).
    pub fn sample_points(&self, pixels: &[(f32, f32)]) -> PointDescriptors {
        let mut data = vec![0.0f32; pixels.len() * self.dim];
        for (row, &(u, v)) in data.chunks_mut(self.dim.max(1)).zip(pixels) {
            self.sample_into(u, v, row);
            normalize(row);
        }
        PointDescriptors {
            dim: self.dim,
            data,
        }
    }

    /// [`sample`](Self::sample) into a caller buffer of length `dim` (no allocation).
    pub fn sample_into(&self, u: f32, v: f32, out: &mut [f32]) {
        let (x0, x1, fx) = axis(u, self.stride_x, self.width);
        let (y0, y1, fy) = axis(v, self.stride_y, self.height);
        let (a, b) = (self.cell(x0, y0), self.cell(x1, y0));
        let (c, d) = (self.cell(x0, y1), self.cell(x1, y1));
        let (w00, w10) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy));
        let (w01, w11) = ((1.0 - fx) * fy, fx * fy);
        for (k, o) in out.iter_mut().enumerate().take(self.dim) {
            *o = w00 * a[k] + w10 * b[k] + w01 * c[k] + w11 * d[k];
        }
    }

    /// Scale every cell to unit L2 norm (cells of norm < 1e-12 stay as they are).
    pub fn l2_normalize_cells(&mut self) {
        if self.dim == 0 {
            return;
        }
        for cell in self.data.chunks_mut(self.dim) {
            let n = cell.iter().map(|v| v * v).sum::<f32>().sqrt();
            if n > 1e-12 {
                cell.iter_mut().for_each(|v| *v /= n);
            }
        }
    }
}

/// Source cells and weight along one axis, torch `area_pixel_compute_source_index` semantics:
/// src = max(0, (dst + 0.5) / stride - 0.5), i1 = min(i0 + 1, n - 1).
#[inline]
pub(crate) fn axis(p: f32, stride: f32, n: u32) -> (u32, u32, f32) {
    let s = ((p + 0.5) / stride - 0.5).max(0.0);
    let i0 = (s.floor() as u32).min(n.saturating_sub(1));
    let i1 = (i0 + 1).min(n.saturating_sub(1));
    let f = (s - i0 as f32).clamp(0.0, 1.0);
    (i0, i1, if i1 == i0 { 0.0 } else { f })
}

/// A model that describes each image on its own.
pub trait PerImageModel: Send + Sync {
    /// Names the model and its weights (e.g. `xfeat@sha256:…`), for cache keys and provenance.
    fn id(&self) -> String;
    fn describe(&self, img: &RgbImage) -> Result<DenseDescriptors>;
    /// Unit descriptors at image pixels `(u, v)` (column, row), row-major `pixels.len() × dim`,
    /// sampled as [`DenseDescriptors::sample`] then L2-normalised; a descriptor of norm < 1e-12
    /// stays zero. Dense per-pixel models override this to sample their full-resolution map and
    /// drop it, instead of returning it.
    fn describe_at(&self, img: &RgbImage, pixels: &[(f32, f32)]) -> Result<PointDescriptors> {
        Ok(self.describe(img)?.sample_points(pixels))
    }

    /// [`Self::describe_at`] read through `cell` x `cell`-pixel cells: for a dense per-pixel
    /// model with `cell` > 1, its map at the cells' centres (each unit), bilinear between them,
    /// then unit (the points of a `describe` grid of that stride); `cell` = 1 is the pixel
    /// itself. Models with a grid of their own (XFeat) ignore `cell`.
    fn describe_at_cells(
        &self,
        img: &RgbImage,
        pixels: &[(f32, f32)],
        cell: u32,
    ) -> Result<PointDescriptors> {
        let _ = cell;
        self.describe_at(img, pixels)
    }
}

/// Descriptors of a list of pixels: row i is `data[i * dim..][..dim]`.
#[derive(Clone, Debug, PartialEq)]
pub struct PointDescriptors {
    pub dim: usize,
    pub data: Vec<f32>,
}

impl PointDescriptors {
    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.dim..(i + 1) * self.dim]
    }
}

/// Scale to unit L2 norm in place (left as is below 1e-12); true when scaled.
pub fn normalize(v: &mut [f32]) -> bool {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 1e-12 {
        v.iter_mut().for_each(|x| *x /= n);
        true
    } else {
        false
    }
}

/// A model that describes two images jointly (each output conditioned on both inputs).
pub trait PairModel: Send + Sync {
    fn id(&self) -> String;
    /// Descriptors of `a` (conditioned on `b`) and of `b` (conditioned on `a`).
    fn describe_pair(
        &self,
        a: &RgbImage,
        b: &RgbImage,
    ) -> Result<(DenseDescriptors, DenseDescriptors)>;
    /// All ordered pairs, src-major (`k = s * K_tgt + t`). Models may override this to
    /// preprocess each image once and batch the forward passes.
    fn describe_pairs(
        &self,
        src: &[RgbImage],
        tgt: &[RgbImage],
    ) -> Result<Vec<(DenseDescriptors, DenseDescriptors)>> {
        let mut out = Vec::with_capacity(src.len() * tgt.len());
        for a in src {
            for b in tgt {
                out.push(self.describe_pair(a, b)?);
            }
        }
        Ok(out)
    }
}

/// All K_src × K_tgt ordered pairs of `model`, src-major (pair `k = s * K_tgt + t`, view1 = src
/// view s, view2 = tgt view t), as the reference (§6.3).
pub fn describe_all_pairs(
    model: &dyn PairModel,
    src: &[RgbImage],
    tgt: &[RgbImage],
) -> Result<Vec<(DenseDescriptors, DenseDescriptors)>> {
    let out = model.describe_pairs(src, tgt)?;
    if out.len() != src.len() * tgt.len() {
        return Err(Error::External {
            what: model.id(),
            message: format!(
                "returned {} pair outputs for {}x{} views",
                out.len(),
                src.len(),
                tgt.len()
            ),
        });
    }
    Ok(out)
}

/// The inference backend in use: `"onnxruntime <version> (<library path>)"`, `"tract (pure
/// Rust)"`, or why none is available. Initialises the backend on first call.
pub fn backend_name() -> String {
    #[cfg(feature = "onnx")]
    {
        crate::onnx::backend_name()
    }
    #[cfg(not(feature = "onnx"))]
    {
        "none (built without the `onnx` feature)".to_string()
    }
}

/// Default location of the bundled XFeat model (`<crate>/models/xfeat.onnx`).
pub fn default_xfeat_path() -> std::path::PathBuf {
    default_model_path("xfeat.onnx")
}

/// A bundled model file: `<crate>/models/<name>`.
pub fn default_model_path(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("models")
        .join(name)
}

/// Serde form of a model path in run files and results: a file under the repository the
/// binary was built from (the bundled `models/`) is written relative to it, so a result JSON
/// names `models/xfeat.onnx` rather than the build machine's folders; reading it back resolves
/// a relative path against that repository when the file is there (the form it was written in).
pub mod model_path_serde {
    use serde::{Deserialize, Deserializer, Serializer};
    use std::path::{Path, PathBuf};

    fn repo() -> &'static Path {
        Path::new(env!("CARGO_MANIFEST_DIR"))
    }

    pub fn serialize<S: Serializer>(p: &Path, s: S) -> Result<S::Ok, S::Error> {
        match p.strip_prefix(repo()) {
            Ok(rel) if !rel.as_os_str().is_empty() => s.collect_str(&rel.display()),
            _ => s.collect_str(&p.display()),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<PathBuf, D::Error> {
        let p = PathBuf::deserialize(d)?;
        if p.is_relative() && !p.as_os_str().is_empty() && repo().join(&p).exists() {
            return Ok(repo().join(p));
        }
        Ok(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundled_model_paths_are_written_relative_to_the_repository() {
        #[derive(serde::Serialize, serde::Deserialize, PartialEq, Debug)]
        struct M {
            #[serde(with = "model_path_serde")]
            model: std::path::PathBuf,
        }
        let bundled = M {
            model: default_xfeat_path(),
        };
        let json = serde_json::to_string(&bundled).unwrap();
        assert_eq!(json, r#"{"model":"models/xfeat.onnx"}"#);
        let back: M = serde_json::from_str(&json).unwrap();
        assert_eq!(back, bundled, "read back as the bundled file");
        let elsewhere = M {
            model: "/opt/models/mine.onnx".into(),
        };
        let json = serde_json::to_string(&elsewhere).unwrap();
        assert_eq!(json, r#"{"model":"/opt/models/mine.onnx"}"#);
        assert_eq!(serde_json::from_str::<M>(&json).unwrap(), elsewhere);
    }

    /// Reference upsampling written independently: torch bilinear, align_corners=False,
    /// output size (oh, ow) from an input grid (h, w).
    fn torch_upsample(g: &DenseDescriptors, ow: usize, oh: usize) -> Vec<f32> {
        let (w, h, d) = (g.width as usize, g.height as usize, g.dim);
        let (sw, sh) = (w as f32 / ow as f32, h as f32 / oh as f32);
        let mut out = vec![0.0; ow * oh * d];
        for y in 0..oh {
            let ry = (sh * (y as f32 + 0.5) - 0.5).max(0.0);
            let y0 = ry as usize;
            let yp = if y0 < h - 1 { 1 } else { 0 };
            let ly = ry - y0 as f32;
            for x in 0..ow {
                let rx = (sw * (x as f32 + 0.5) - 0.5).max(0.0);
                let x0 = rx as usize;
                let xp = if x0 < w - 1 { 1 } else { 0 };
                let lx = rx - x0 as f32;
                for k in 0..d {
                    let v = |yy: usize, xx: usize| g.data[(yy * w + xx) * d + k];
                    out[(y * ow + x) * d + k] = (1.0 - ly)
                        * ((1.0 - lx) * v(y0, x0) + lx * v(y0, x0 + xp))
                        + ly * ((1.0 - lx) * v(y0 + yp, x0) + lx * v(y0 + yp, x0 + xp));
                }
            }
        }
        out
    }

    #[test]
    fn sample_matches_torch_bilinear_upsampling() {
        // MASt3R case: 512x375 grid -> 960x704 image, and an XFeat-like stride-8 case.
        for &(w, h, ow, oh) in &[(512usize, 375usize, 960usize, 704usize), (20, 15, 160, 120)] {
            let d = 3;
            let data: Vec<f32> = (0..w * h * d)
                .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
                .collect();
            let g = DenseDescriptors::new(
                w as u32,
                h as u32,
                d,
                data,
                ow as f32 / w as f32,
                oh as f32 / h as f32,
            )
            .unwrap();
            let want = torch_upsample(&g, ow, oh);
            let mut max = 0f32;
            for y in (0..oh).step_by(7).chain([0, oh - 1]) {
                for x in (0..ow).step_by(5).chain([0, ow - 1]) {
                    let s = g.sample(x as f32, y as f32);
                    for k in 0..d {
                        max = max.max((s[k] - want[(y * ow + x) * d + k]).abs());
                    }
                }
            }
            assert!(max < 1e-4, "max difference {max}");
        }
    }

    #[test]
    fn new_rejects_wrong_sizes() {
        assert!(DenseDescriptors::new(2, 2, 3, vec![0.0; 11], 8.0, 8.0).is_err());
        assert!(DenseDescriptors::new(2, 2, 3, vec![0.0; 12], 0.0, 8.0).is_err());
        assert!(DenseDescriptors::new(2, 2, 3, vec![0.0; 12], 8.0, 8.0).is_ok());
    }
}
