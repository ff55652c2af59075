//! MASt3R as a pair-conditioned model, with the reference's pre- and postprocessing (§6, §13).
//!
//! ONNX contract (written by `models/export_mast3r.py`): inputs `img1`, `img2` float32
//! [B, 3, 384, 512] in [-1, 1]; outputs `desc_1`, `desc_2` float32 [B, 384, 512, 24] (unit-norm
//! per pixel); other outputs (pts3d, conf) are ignored. The weights sit in an external-data
//! file beside the graph (`X.onnx.data`); both belong to the model id. Verified against the real
//! MASt3R code (random small weights) in tests/mast3r_export.rs.
//!
//! Preprocessing per image (reference collate): resize so the long side is 512 (PIL LANCZOS when
//! shrinking, BICUBIC when enlarging; size rounded half-to-even as Python's `round`), so a
//! 960×704 frame becomes 512×375; `x = (u8/255 − 0.5)/0.5`; zero rows appended at the bottom up
//! to 384. Postprocessing: drop the padded rows; the 512×375 grid then maps back to the original
//! frame with strides 960/512 and 704/375, and [`DenseDescriptors::sample`] reproduces the
//! reference's bilinear (align_corners=False) upsampling to 704×960 pixel by pixel without
//! materialising it (1 GB per side at K = 4).
//!
//! The image crate's Lanczos3 is separable with an f32 intermediate; PIL rounds to u8 between
//! its two passes, so inputs can differ from the reference by about one grey level.

use super::{preprocess, DenseDescriptors, PairModel};
use crate::error::{Error, Result};
use crate::onnx::{file_id, OnnxModel};
use image::RgbImage;
use std::path::Path;

pub const IN_H: usize = 384;
pub const IN_W: usize = 512;
pub const INPUTS: [&str; 2] = ["img1", "img2"];
pub const OUTPUTS: [&str; 2] = ["desc_1", "desc_2"];
const EXPECTED: &str = "a MASt3R ONNX model (inputs `img1`, `img2` float32 [B,3,384,512] in [-1,1]; outputs `desc_1`, `desc_2` [B,384,512,D])";

/// One preprocessed image: the padded (3, 384, 512) tensor and the size before padding.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub tensor: Vec<f32>,
    /// Resized width and height (512 × 375 for a 960×704 frame).
    pub resized: (usize, usize),
    /// Original image size.
    pub original: (u32, u32),
}

/// The reference's collate step for one image.
pub fn prepare(img: &RgbImage) -> Result<Prepared> {
    let (w, h) = img.dimensions();
    let s = w.max(h) as f64;
    if s == 0.0 {
        return Err(Error::Invalid("MASt3R: empty image".into()));
    }
    let nw = preprocess::round_half_even(w as f64 * IN_W as f64 / s).max(1) as u32;
    let nh = preprocess::round_half_even(h as f64 * IN_W as f64 / s).max(1) as u32;
    if nw as usize != IN_W || nh as usize > IN_H {
        return Err(Error::Invalid(format!(
            "MASt3R ONNX takes landscape frames that resize to 512 wide and at most 384 high; {w}x{h} resizes to {nw}x{nh}"
        )));
    }
    let filter = if s > IN_W as f64 {
        image::imageops::FilterType::Lanczos3
    } else {
        image::imageops::FilterType::CatmullRom
    };
    let resized = if (nw, nh) == (w, h) {
        img.clone()
    } else {
        image::imageops::resize(img, nw, nh, filter)
    };
    let plane = IN_H * IN_W;
    let mut tensor = vec![0.0f32; 3 * plane];
    for (x, y, p) in resized.enumerate_pixels() {
        let i = y as usize * IN_W + x as usize;
        for c in 0..3 {
            tensor[c * plane + i] = (p[c] as f32 / 255.0 - 0.5) / 0.5;
        }
    }
    Ok(Prepared {
        tensor,
        resized: (nw as usize, nh as usize),
        original: (w, h),
    })
}

/// Crop one [384, 512, D] output to the unpadded rows and tie it to the original image.
pub fn postprocess(desc: &[f32], dim: usize, p: &Prepared) -> Result<DenseDescriptors> {
    let (rw, rh) = p.resized;
    let data = desc[..rh * IN_W * dim].to_vec();
    DenseDescriptors::new(
        rw as u32,
        rh as u32,
        dim,
        data,
        p.original.0 as f32 / rw as f32,
        p.original.1 as f32 / rh as f32,
    )
}

#[derive(Debug)]
pub struct Mast3r {
    model: OnnxModel,
    id: String,
    /// Pairs per forward pass (1 unless the model was exported with a dynamic batch axis and
    /// there is memory for more).
    pub max_batch: usize,
}

impl Mast3r {
    pub fn load(path: &Path) -> Result<Mast3r> {
        // The id first: it reads the external-data file (all the weights) and names it when it
        // is missing, which the runtimes report less plainly.
        // an input like any other: a FIFO or device would block or never end the read
        crate::io::limits::check_regular(path)?;
        let id = format!("mast3r@{}", file_id(path)?);
        let model = OnnxModel::load(path, &INPUTS, &OUTPUTS, EXPECTED)?;
        Ok(Mast3r {
            model,
            id,
            max_batch: 1,
        })
    }

    fn run_batch(
        &self,
        pairs: &[(&Prepared, &Prepared)],
    ) -> Result<Vec<(DenseDescriptors, DenseDescriptors)>> {
        let b = pairs.len();
        let n = 3 * IN_H * IN_W;
        let (mut x1, mut x2) = (Vec::with_capacity(b * n), Vec::with_capacity(b * n));
        for (a, c) in pairs {
            x1.extend_from_slice(&a.tensor);
            x2.extend_from_slice(&c.tensor);
        }
        let shape = vec![b as i64, 3, IN_H as i64, IN_W as i64];
        let out = self.model.run(
            vec![(INPUTS[0], shape.clone(), x1), (INPUTS[1], shape, x2)],
            &OUTPUTS,
        )?;
        let mut dims = [0usize; 2];
        for (k, (s, _)) in out.iter().enumerate() {
            if s.len() != 4
                || s[0] != b as i64
                || s[1] != IN_H as i64
                || s[2] != IN_W as i64
                || s[3] < 1
            {
                return Err(Error::format(
                    &self.model.path,
                    OUTPUTS[k],
                    format!("shape [{b}, {IN_H}, {IN_W}, D]"),
                    format!("{s:?}"),
                ));
            }
            dims[k] = s[3] as usize;
        }
        let per = |k: usize| IN_H * IN_W * dims[k];
        let mut res = Vec::with_capacity(b);
        for (i, (a, c)) in pairs.iter().enumerate() {
            let d1 = &out[0].1[i * per(0)..(i + 1) * per(0)];
            let d2 = &out[1].1[i * per(1)..(i + 1) * per(1)];
            res.push((postprocess(d1, dims[0], a)?, postprocess(d2, dims[1], c)?));
        }
        Ok(res)
    }
}

impl PairModel for Mast3r {
    fn id(&self) -> String {
        self.id.clone()
    }

    fn describe_pair(
        &self,
        a: &RgbImage,
        b: &RgbImage,
    ) -> Result<(DenseDescriptors, DenseDescriptors)> {
        let (pa, pb) = (prepare(a)?, prepare(b)?);
        let mut r = self.run_batch(&[(&pa, &pb)])?;
        r.pop()
            .ok_or_else(|| Error::Missing("MASt3R returned no pair".into()))
    }

    /// Each image is preprocessed once; pairs go src-major in batches of `max_batch`.
    fn describe_pairs(
        &self,
        src: &[RgbImage],
        tgt: &[RgbImage],
    ) -> Result<Vec<(DenseDescriptors, DenseDescriptors)>> {
        let ps = src.iter().map(prepare).collect::<Result<Vec<_>>>()?;
        let pt = tgt.iter().map(prepare).collect::<Result<Vec<_>>>()?;
        let pairs: Vec<(&Prepared, &Prepared)> = ps
            .iter()
            .flat_map(|a| pt.iter().map(move |b| (a, b)))
            .collect();
        let mut out = Vec::with_capacity(pairs.len());
        for chunk in pairs.chunks(self.max_batch.max(1)) {
            out.extend(self.run_batch(chunk)?);
        }
        Ok(out)
    }
}
