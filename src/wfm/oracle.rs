//! The `oracle` backend: the dataset's real RGB frames in place of generated ones (the paper's
//! "C-GenReg (Oracle)" row). Source colour frames then target colour frames, in the same order
//! as the depth video. 7-Scenes colour frames are 640x480 JPEG; they are returned at their own
//! size unless `resize_to` is set (bilinear, half-pixel centres).

use super::backend::{
    now_unix, resize_bilinear, GenerateRequest, Generation, Provenance, WfmBackend,
};
use crate::error::{Error, Result};
use rayon::prelude::*;

#[derive(Clone, Debug, Default)]
pub struct OracleBackend {
    /// Output size (width, height); None keeps the dataset's size.
    pub resize_to: Option<(u32, u32)>,
}

pub const ORACLE_MODEL: &str = "oracle (real RGB)";

impl WfmBackend for OracleBackend {
    fn id(&self) -> String {
        match self.resize_to {
            None => "oracle".into(),
            Some((w, h)) => format!("oracle@{w}x{h}"),
        }
    }

    fn generate(&self, req: &GenerateRequest) -> Result<Generation> {
        let (Some(src), Some(tgt)) = (&req.source_color, &req.target_color) else {
            return Err(Error::Missing(format!(
                "oracle backend: pair `{}` has no real colour frames (source_color/target_color); \
                 the oracle needs an RGB-D dataset with colour images",
                req.pair_id
            )));
        };
        let n_depth = req.depth_video.len();
        if n_depth != 0 && src.len() + tgt.len() != n_depth {
            return Err(Error::Shape(format!(
                "oracle backend: pair `{}` has {} + {} colour frames but a {n_depth}-frame depth video",
                req.pair_id,
                src.len(),
                tgt.len()
            )));
        }
        let frames: Vec<image::RgbImage> = src
            .par_iter()
            .chain(tgt.par_iter())
            .map(|p| {
                let bytes = std::fs::read(p).map_err(|e| Error::io(p, e))?;
                let img = image::load_from_memory(&bytes)
                    .map_err(|e| {
                        Error::format(
                            p,
                            "image",
                            "a readable colour image (JPEG/PNG)",
                            e.to_string(),
                        )
                    })?
                    .to_rgb8();
                Ok(match self.resize_to {
                    Some((w, h)) => resize_bilinear(&img, w, h),
                    None => img,
                })
            })
            .collect::<Result<_>>()?;
        if let Some(f) = frames.first() {
            let d = f.dimensions();
            let all = src.iter().chain(tgt.iter());
            if let Some((p, g)) = all.zip(&frames).find(|(_, g)| g.dimensions() != d) {
                return Err(Error::format(
                    p,
                    "image size",
                    format!("{}x{} like the first colour frame", d.0, d.1),
                    format!("{}x{}", g.width(), g.height()),
                ));
            }
        }
        let provenance = Provenance {
            backend: self.id(),
            model: ORACLE_MODEL.into(),
            command: None,
            prompt: String::new(),
            seed: req.seed,
            params: serde_json::json!({
                "resize_to": self.resize_to,
                "source_frames": src.len(),
                "target_frames": tgt.len(),
                "first_source": src.first().map(|p| p.to_string_lossy().into_owned()),
                "first_target": tgt.first().map(|p| p.to_string_lossy().into_owned()),
            }),
            created_unix: now_unix(),
            frame_count: frames.len(),
            warnings: vec!["real RGB frames, not generated: an upper bound, not the method".into()],
        };
        Ok(Generation { frames, provenance })
    }
}
