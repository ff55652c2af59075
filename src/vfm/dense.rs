//! Dense per-pixel descriptors: DISK (`models/disk.onnx`, 128-D) and ALIKE
//! (`models/alike-t.onnx`, 64-D; `alike-n.onnx`, 128-D).
//!
//! Model contract (written by `models/export_disk.py` / `models/export_alike.py`): input `image`
//! float32 (B, 3, H, W), RGB in [0, 1], H and W multiples of 16 (DISK) or 32 (ALIKE); output
//! `descriptors` (B, D, H, W) at full input resolution, not normalised (plus `heatmap`, unused).
//! Other sizes are zero-padded at the bottom and right and the maps read only inside the image, as
//! kornia's `pad_if_not_divisible` and ALIKE's `extract_dense_map` do, so descriptor pixel (u, v)
//! is image pixel (u, v): no resize.
//!
//! A full-resolution map is large (960×704×128 f32 = 346 MB), so [`DenseModel::describe_at`]
//! reads the requested pixels from the runtime's own output buffer and lets it go when the call
//! returns: at most one map is alive per call, whatever K is. [`PerImageModel::describe`] (the
//! grid the pipeline caches per view) samples the map at the centres of `grid_stride`-pixel cells
//! ([`DEFAULT_GRID_STRIDE`]) before dropping it; [`DenseModel::describe_full`] keeps every pixel.

use super::{axis, normalize, DenseDescriptors, PerImageModel, PointDescriptors};
use crate::error::{Error, Result};
use crate::onnx::{file_id, OnnxModel};
use image::RgbImage;
use std::path::Path;

pub const INPUT: &str = "image";
pub const OUTPUT: &str = "descriptors";

/// Pixels per cell of the grid [`PerImageModel::describe`] returns (960×704 -> 240×176 cells).
pub const DEFAULT_GRID_STRIDE: u32 = 4;

/// Which dense network a file holds (they differ in the size multiple and the message only).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DenseKind {
    Disk,
    Alike,
}

impl DenseKind {
    pub fn name(self) -> &'static str {
        match self {
            DenseKind::Disk => "disk",
            DenseKind::Alike => "alike",
        }
    }

    /// H and W of the network input must be multiples of this.
    pub fn multiple(self) -> u32 {
        match self {
            DenseKind::Disk => 16,
            DenseKind::Alike => 32,
        }
    }

    fn expected(self) -> String {
        let m = self.multiple();
        format!(
            "a {} ONNX model (input `image` float32 [B,3,H,W] RGB in [0,1], H and W multiples of \
             {m}; output `descriptors` [B,D,H,W]; see models/export_{}.py)",
            self.name(),
            self.name()
        )
    }
}

#[derive(Debug)]
pub struct DenseModel {
    model: OnnxModel,
    kind: DenseKind,
    id: String,
    grid_stride: u32,
}

/// One run's descriptor map, borrowed from the runtime: planar (dim, padded h, padded w), read
/// only inside the image (`width` × `height`).
struct MapView<'a> {
    dim: usize,
    pw: usize,
    plane: usize,
    width: u32,
    height: u32,
    data: &'a [f32],
}

impl MapView<'_> {
    /// Bilinear at image pixel (u, v) with half-pixel centres and edge clamping at the image
    /// border (stride 1: integer pixels are read exactly), as [`DenseDescriptors::sample`].
    fn sample_into(&self, u: f32, v: f32, out: &mut [f32]) {
        let (x0, x1, fx) = axis(u, 1.0, self.width);
        let (y0, y1, fy) = axis(v, 1.0, self.height);
        let (x0, x1, y0, y1) = (x0 as usize, x1 as usize, y0 as usize, y1 as usize);
        let (i00, i10) = (y0 * self.pw + x0, y0 * self.pw + x1);
        let (i01, i11) = (y1 * self.pw + x0, y1 * self.pw + x1);
        let (w00, w10) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy));
        let (w01, w11) = ((1.0 - fx) * fy, fx * fy);
        for (c, o) in out.iter_mut().enumerate().take(self.dim) {
            let p = &self.data[c * self.plane..(c + 1) * self.plane];
            *o = w00 * p[i00] + w10 * p[i10] + w01 * p[i01] + w11 * p[i11];
        }
    }
}

impl DenseModel {
    /// Load a DISK or ALIKE export. Under tract, a model it cannot analyse or run (tried on a
    /// small input here, so that it fails at load time and not mid-pipeline) is
    /// [`Error::NeedsNativeRuntime`].
    pub fn load(path: &Path, kind: DenseKind) -> Result<DenseModel> {
        let expected = kind.expected();
        let on_tract = crate::onnx::backend_info()?.kind == "tract";
        // an input like any other: a FIFO or device would block or never end the read
        crate::io::limits::check_regular(path)?;
        let model = match OnnxModel::load(path, &[INPUT], &[OUTPUT], &expected) {
            Ok(m) => m,
            Err(e @ Error::Format { .. }) if on_tract && path.is_file() => {
                return Err(Error::NeedsNativeRuntime {
                    model: path.to_path_buf(),
                    reason: e.to_string(),
                })
            }
            Err(e) => return Err(e),
        };
        let id = format!("{}@{}", kind.name(), file_id(path)?);
        let m = DenseModel {
            model,
            kind,
            id,
            grid_stride: DEFAULT_GRID_STRIDE,
        };
        if on_tract {
            let probe = RgbImage::new(kind.multiple() * 2, kind.multiple() * 2);
            if let Err(e) = m.describe_at(&probe, &[(0.0, 0.0)]) {
                return Err(Error::NeedsNativeRuntime {
                    model: path.to_path_buf(),
                    reason: e.to_string(),
                });
            }
        }
        Ok(m)
    }

    /// The model of a `VfmSpec::Disk` / `VfmSpec::Alike` (anything else is refused).
    pub fn load_spec(spec: &super::VfmSpec, path: &Path) -> Result<DenseModel> {
        use super::VfmSpec;
        match spec {
            VfmSpec::Disk { .. } => DenseModel::load(path, DenseKind::Disk),
            VfmSpec::Alike { .. } => DenseModel::load(path, DenseKind::Alike),
            other => Err(Error::Invalid(format!(
                "{}: {} is not a dense per-pixel VFM",
                path.display(),
                other.name()
            ))),
        }
    }

    pub fn load_disk(path: &Path) -> Result<DenseModel> {
        DenseModel::load(path, DenseKind::Disk)
    }

    pub fn load_alike(path: &Path) -> Result<DenseModel> {
        DenseModel::load(path, DenseKind::Alike)
    }

    pub fn kind(&self) -> DenseKind {
        self.kind
    }

    /// The grid [`PerImageModel::describe`] returns has cells of `s` × `s` pixels (s >= 1).
    pub fn with_grid_stride(mut self, s: u32) -> DenseModel {
        self.grid_stride = s.max(1);
        self
    }

    /// Run on `img` (padded to the multiple) and hand the map to `f`; the map is freed after.
    fn with_map<R>(&self, img: &RgbImage, f: impl FnOnce(&MapView) -> Result<R>) -> Result<R> {
        let (w, h) = img.dimensions();
        if w == 0 || h == 0 {
            return Err(Error::Invalid(format!(
                "{}: an empty {w}x{h} image",
                self.kind.name()
            )));
        }
        let m = self.kind.multiple();
        let (pw, ph) = (w.div_ceil(m) * m, h.div_ceil(m) * m);
        let (pwu, phu) = (pw as usize, ph as usize);
        let plane = pwu * phu;
        let mut x = vec![0.0f32; 3 * plane];
        for (px, py, p) in img.enumerate_pixels() {
            let i = py as usize * pwu + px as usize;
            for c in 0..3 {
                x[c * plane + i] = p[c] as f32 / 255.0;
            }
        }
        let path = &self.model.path;
        self.model.run_with(
            vec![(INPUT, vec![1, 3, ph as i64, pw as i64], x)],
            OUTPUT,
            |shape, data| {
                let ok = shape.len() == 4
                    && shape[0] == 1
                    && shape[1] > 0
                    && shape[2] == ph as i64
                    && shape[3] == pw as i64
                    && data.len() == shape[1] as usize * plane;
                if !ok {
                    return Err(Error::format(
                        path,
                        "output descriptors",
                        format!("shape [1, D, {ph}, {pw}]"),
                        format!("{shape:?} with {} values", data.len()),
                    ));
                }
                f(&MapView {
                    dim: shape[1] as usize,
                    pw: pwu,
                    plane,
                    width: w,
                    height: h,
                    data,
                })
            },
        )
    }

    /// Every pixel's unit descriptor (the full map: 346 MB at 960×704×128; for checks).
    pub fn describe_full(&self, img: &RgbImage) -> Result<DenseDescriptors> {
        self.describe_grid(img, 1)
    }

    /// The map sampled at the centres of `s` × `s`-pixel cells, each cell L2-normalised.
    fn describe_grid(&self, img: &RgbImage, s: u32) -> Result<DenseDescriptors> {
        let (w, h) = img.dimensions();
        let (gw, gh) = (w.div_ceil(s), h.div_ceil(s));
        let (sx, sy) = (w as f32 / gw as f32, h as f32 / gh as f32);
        self.with_map(img, |m| {
            let mut data = vec![0.0f32; gw as usize * gh as usize * m.dim];
            for (i, cell) in data.chunks_mut(m.dim).enumerate() {
                let (gx, gy) = ((i % gw as usize) as f32, (i / gw as usize) as f32);
                m.sample_into((gx + 0.5) * sx - 0.5, (gy + 0.5) * sy - 0.5, cell);
                normalize(cell);
            }
            DenseDescriptors::new(gw, gh, m.dim, data, sx, sy)
        })
    }
}

impl PerImageModel for DenseModel {
    fn id(&self) -> String {
        self.id.clone()
    }

    /// The map on a grid of `grid_stride`-pixel cells (see the module docs).
    fn describe(&self, img: &RgbImage) -> Result<DenseDescriptors> {
        self.describe_grid(img, self.grid_stride)
    }

    /// Bilinear at each pixel of the full-resolution map, L2-normalised; the map is dropped
    /// before this returns.
    fn describe_at(&self, img: &RgbImage, pixels: &[(f32, f32)]) -> Result<PointDescriptors> {
        self.with_map(img, |m| {
            let mut data = vec![0.0f32; pixels.len() * m.dim];
            for (row, &(u, v)) in data.chunks_mut(m.dim).zip(pixels) {
                m.sample_into(u, v, row);
                normalize(row);
            }
            Ok(PointDescriptors { dim: m.dim, data })
        })
    }

    /// `cell` > 1: the map on a grid of `cell`-pixel cells, sampled at the pixels, both
    /// dropped before this returns.
    fn describe_at_cells(
        &self,
        img: &RgbImage,
        pixels: &[(f32, f32)],
        cell: u32,
    ) -> Result<PointDescriptors> {
        if cell <= 1 {
            return self.describe_at(img, pixels);
        }
        Ok(self.describe_grid(img, cell)?.sample_points(pixels))
    }
}
