//! XFeat dense descriptors (the default per-image model) from `models/xfeat.onnx`.
//!
//! Model contract (written by `models/export_xfeat.py`): input `image` float32 (B, 3, H, W), RGB
//! in [0, 1], H and W multiples of 32; output `feats` (B, 64, H/8, W/8), not normalised (plus
//! `keypoints` and `heatmap`, unused here). The network averages RGB to grey and
//! instance-normalises internally, so the image goes in as plain RGB.
//!
//! Sizes that are not multiples of 32 are resized down to the nearest multiple (bilinear,
//! half-pixel centres, as XFeat's own `preprocess_tensor`); the descriptor grid's strides record
//! the mapping back to the original pixels (exactly 8 when no resize was needed).

use super::{preprocess, DenseDescriptors, PerImageModel};
use crate::error::{Error, Result};
use crate::onnx::{file_id, OnnxModel};
use image::RgbImage;
use std::path::Path;

pub const INPUT: &str = "image";
pub const OUTPUT: &str = "feats";
const EXPECTED: &str =
    "an XFeat ONNX model (input `image` float32 [B,3,H,W] RGB in [0,1], output `feats` [B,64,H/8,W/8])";

#[derive(Debug)]
pub struct XFeat {
    model: OnnxModel,
    id: String,
}

impl XFeat {
    pub fn load(path: &Path) -> Result<XFeat> {
        // an input like any other: a FIFO or device would block or never end the read
        crate::io::limits::check_regular(path)?;
        let model = OnnxModel::load(path, &[INPUT], &[OUTPUT], EXPECTED)?;
        let id = format!("xfeat@{}", file_id(path)?);
        Ok(XFeat { model, id })
    }

    /// The bundled `models/xfeat.onnx`.
    pub fn load_default() -> Result<XFeat> {
        XFeat::load(&super::default_xfeat_path())
    }
}

impl PerImageModel for XFeat {
    fn id(&self) -> String {
        self.id.clone()
    }

    fn describe(&self, img: &RgbImage) -> Result<DenseDescriptors> {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let (mw, mh) = (w / 32 * 32, h / 32 * 32);
        if mw == 0 || mh == 0 {
            return Err(Error::Invalid(format!(
                "XFeat needs images of at least 32x32 pixels, got {w}x{h}"
            )));
        }
        let mut x = preprocess::to_chw(img, |v| v as f32 / 255.0);
        if (mw, mh) != (w, h) {
            x = preprocess::resize_bilinear_chw(&x, 3, (w, h), (mw, mh));
        }
        let out = self.model.run(
            vec![(INPUT, vec![1, 3, mh as i64, mw as i64], x)],
            &[OUTPUT],
        )?;
        let (shape, data) = &out[0];
        let (gw, gh) = (mw / 8, mh / 8);
        if shape.len() != 4 || shape[0] != 1 || shape[2] != gh as i64 || shape[3] != gw as i64 {
            return Err(Error::format(
                &self.model.path,
                "output feats",
                format!("shape [1, C, {gh}, {gw}]"),
                format!("{shape:?}"),
            ));
        }
        let dim = shape[1] as usize;
        // (C, H, W) -> (H, W, C)
        let plane = gw * gh;
        let mut cells = vec![0.0f32; plane * dim];
        for c in 0..dim {
            let src = &data[c * plane..(c + 1) * plane];
            for (i, &v) in src.iter().enumerate() {
                cells[i * dim + c] = v;
            }
        }
        let mut d = DenseDescriptors::new(
            gw as u32,
            gh as u32,
            dim,
            cells,
            8.0 * w as f32 / mw as f32,
            8.0 * h as f32 / mh as f32,
        )?;
        d.l2_normalize_cells();
        Ok(d)
    }
}
