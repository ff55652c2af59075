//! The one interface every WFM backend implements, and the provenance each output carries.

use super::prompt::Prompt;
use crate::error::Result;
use image::RgbImage;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// What a backend is asked to generate: the RGB video for one pair's depth video.
#[derive(Clone, Debug)]
pub struct GenerateRequest {
    /// Stable pair id (e.g. "redkitchen/0-5", or a reference line index for `cached`).
    pub pair_id: String,
    /// The depth-control frames (grey in 3 channels, src then tgt).
    pub depth_video: Vec<RgbImage>,
    /// The same video already written as an mp4, when there is one (Cosmos reads it as is;
    /// `cached` matches its file name against the JSONL spec).
    pub depth_video_path: Option<PathBuf>,
    pub prompt: Prompt,
    pub seed: u64,
    /// Real colour frames of the source and target fragments, for the `oracle` backend only.
    pub source_color: Option<Vec<PathBuf>>,
    pub target_color: Option<Vec<PathBuf>>,
}

/// Where frames came from, stored with them in the cache and shown in the UI.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// The backend id, e.g. "cosmos:torchrun", "cached:/data/gen", "oracle",
    /// "builtin-depthshade-v1".
    pub backend: String,
    /// What produced the pixels, in words (model name, or "oracle (real RGB)", or
    /// "builtin-depthshade-v1: NOT a WFM ...").
    pub model: String,
    /// The argument vector that ran, for external generators.
    pub command: Option<Vec<String>>,
    /// The prompt text actually used (Cosmos' `prompt.txt` when present).
    pub prompt: String,
    pub seed: u64,
    pub params: serde_json::Value,
    pub created_unix: u64,
    pub frame_count: usize,
    /// Things a user should know (prompt mismatch, frame count differs, ...).
    pub warnings: Vec<String>,
}

/// The generated frames with their provenance.
#[derive(Clone, Debug)]
pub struct Generation {
    pub frames: Vec<RgbImage>,
    pub provenance: Provenance,
}

/// A world-foundation-model backend (or a stand-in for one, labelled as such).
pub trait WfmBackend: Send + Sync {
    /// Identifies the backend and its configuration for caching and display.
    fn id(&self) -> String;
    /// Produce the RGB frames for one pair's depth video.
    fn generate(&self, req: &GenerateRequest) -> Result<Generation>;

    /// The size of every frame when the backend fixes it (the built-in shading), so that what
    /// follows the generation can be planned before it runs; None when only the frames say.
    fn frame_size(&self) -> Option<(u32, u32)> {
        None
    }

    /// Generate several requests; a backend that amortises start-up (Cosmos loads a 7B model
    /// per run) does them in one run. One result per request, in order.
    fn generate_batch(&self, reqs: &[GenerateRequest]) -> Vec<Result<Generation>> {
        reqs.iter().map(|r| self.generate(r)).collect()
    }
}

pub(crate) fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// A file-name-safe version of a pair id.
pub(crate) fn sanitize(id: &str) -> String {
    let s: String = id
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.' | '@') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() || s.chars().all(|c| c == '.') {
        "pair".into()
    } else {
        s
    }
}

/// Bilinear resize with half-pixel centres (what `cv2.INTER_LINEAR` does when upscaling).
pub fn resize_bilinear(img: &RgbImage, w: u32, h: u32) -> RgbImage {
    if img.dimensions() == (w, h) {
        return img.clone();
    }
    let (sw, sh) = (img.width() as f32, img.height() as f32);
    let (iw, ih) = (img.width() as i64, img.height() as i64);
    let src = img.as_raw();
    let mut out = RgbImage::new(w, h);
    let sx = sw / w as f32;
    let sy = sh / h as f32;
    let xs: Vec<(usize, usize, f32)> = (0..w)
        .map(|x| {
            let fx = ((x as f32 + 0.5) * sx - 0.5).max(0.0);
            let x0 = (fx.floor() as i64).min(iw - 1);
            let x1 = (x0 + 1).min(iw - 1);
            (x0 as usize, x1 as usize, fx - x0 as f32)
        })
        .collect();
    let ow = w as usize;
    let buf: &mut [u8] = out.as_mut();
    for y in 0..h as usize {
        let fy = ((y as f32 + 0.5) * sy - 0.5).max(0.0);
        let y0 = (fy.floor() as i64).min(ih - 1);
        let y1 = (y0 + 1).min(ih - 1);
        let ty = fy - y0 as f32;
        let (r0, r1) = (y0 as usize * iw as usize, y1 as usize * iw as usize);
        for (x, &(x0, x1, tx)) in xs.iter().enumerate() {
            for c in 0..3 {
                let a = src[3 * (r0 + x0) + c] as f32;
                let b = src[3 * (r0 + x1) + c] as f32;
                let d = src[3 * (r1 + x0) + c] as f32;
                let e = src[3 * (r1 + x1) + c] as f32;
                let top = a + (b - a) * tx;
                let bot = d + (e - d) * tx;
                buf[3 * (y * ow + x) + c] = (top + (bot - top) * ty + 0.5) as u8;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sanitize_ids() {
        assert_eq!(sanitize("redkitchen/0-5"), "redkitchen_0-5");
        assert_eq!(sanitize(".."), "pair");
        assert_eq!(sanitize(""), "pair");
    }

    #[test]
    fn bilinear_matches_hand_values() {
        // 2x1 -> 4x1: half-pixel centres give 0, 0.25, 0.75, 1 of the way (cv2 INTER_LINEAR).
        let img = RgbImage::from_raw(2, 1, vec![0, 0, 0, 100, 100, 100]).unwrap();
        let r = resize_bilinear(&img, 4, 1);
        let v: Vec<u8> = r.pixels().map(|p| p[0]).collect();
        assert_eq!(v, vec![0, 25, 75, 100]);
        // Constant images stay constant at any size.
        let c = RgbImage::from_pixel(64, 48, image::Rgb([7, 8, 9]));
        assert!(resize_bilinear(&c, 96, 70)
            .pixels()
            .all(|p| p.0 == [7, 8, 9]));
    }
}
