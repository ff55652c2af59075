//! The depth-control video exactly as the reference builds it (reference §1.2, §1.3).
//!
//! Per frame, independently: raw 16-bit millimetres, 65535 -> 0 (invalid), divide by 1000,
//! clip to [0, 4] m, `valid = depth > 0`, inverse depth `1 / (depth + 1e-8)` on valid pixels,
//! min-max over the valid pixels `n = (inv - min) / (max - min + 1e-8)`, then the truncating
//! cast `u8(n * 255)`; invalid pixels are 0. Near is bright, far is dark.
//!
//! Arithmetic is f64, which is what numpy gives for `uint16 / 1000`. One consequence worth
//! knowing: because of the `+ 1e-8` in the denominator the nearest pixel of a frame gives
//! `n` slightly below 1, so it comes out as 254, not 255 (as in the reference).
//!
//! The pair video is `src` frames then `tgt` frames (L = 50 each in the reference), grey
//! replicated into three channels, no separator frames; it is written at 30 fps.

use crate::error::Result;
use crate::io::depth_png::{read_depth_png, DepthImage};
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use std::path::Path;

/// Depth beyond this (metres) is clipped to it before inversion.
pub const CLIP_METERS: f64 = 4.0;
/// The epsilon of the reference, in both the inversion and the normalisation.
pub const EPS: f64 = 1e-8;
/// Frames per fragment in the reference.
pub const FRAMES_PER_FRAGMENT: usize = 50;
/// Frame rate of the depth video and of Cosmos' output.
pub const FPS: u32 = 30;

/// Encode one depth frame as the reference's 8-bit inverse-depth grey image.
pub fn encode_depth_frame(depth: &DepthImage) -> GrayImage {
    encode_depth_frame_clip(depth, CLIP_METERS)
}

/// [`encode_depth_frame`] with another clip distance (metres): LiDAR frames keep their range.
pub fn encode_depth_frame_clip(depth: &DepthImage, clip_m: f64) -> GrayImage {
    let inv: Vec<f64> = depth
        .data
        .iter()
        .map(|&raw| {
            let raw = if raw == u16::MAX { 0 } else { raw };
            let m = (raw as f64 / 1000.0).clamp(0.0, clip_m);
            if m > 0.0 {
                1.0 / (m + EPS)
            } else {
                0.0
            }
        })
        .collect();
    let (lo, hi) = depth
        .data
        .iter()
        .zip(&inv)
        .filter(|(&raw, _)| raw != 0 && raw != u16::MAX)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, &v)| {
            (lo.min(v), hi.max(v))
        });
    let mut out = GrayImage::new(depth.width, depth.height);
    if lo.is_finite() {
        let scale = 1.0 / (hi - lo + EPS);
        for ((o, &v), &raw) in out.as_mut().iter_mut().zip(&inv).zip(&depth.data) {
            if raw != 0 && raw != u16::MAX {
                // `as u8` truncates (and saturates), like numpy's astype(uint8) on [0, 255).
                *o = ((v - lo) * scale * 255.0) as u8;
            }
        }
    }
    out
}

/// Replicate a grey frame into three identical channels (cv2 GRAY2BGR, which is also RGB).
pub fn gray_to_rgb(g: &GrayImage) -> RgbImage {
    let mut out = RgbImage::new(g.width(), g.height());
    for (o, &v) in out.as_mut().chunks_exact_mut(3).zip(g.as_raw()) {
        o.copy_from_slice(&[v, v, v]);
    }
    out
}

/// The pair video: encoded `src` frames then encoded `tgt` frames, grey in three channels.
pub fn build_pair_video(src: &[DepthImage], tgt: &[DepthImage]) -> Vec<RgbImage> {
    build_pair_video_clip(src, tgt, CLIP_METERS)
}

/// [`build_pair_video`] with another clip distance.
pub fn build_pair_video_clip(src: &[DepthImage], tgt: &[DepthImage], clip_m: f64) -> Vec<RgbImage> {
    src.par_iter()
        .chain(tgt.par_iter())
        .map(|d| gray_to_rgb(&encode_depth_frame_clip(d, clip_m)))
        .collect()
}

/// Read the depth PNGs of both fragments and build the pair video. All frames must have the
/// same size (one video); the first mismatching file is named in the error.
pub fn pair_video_from_files<P: AsRef<Path> + Sync>(src: &[P], tgt: &[P]) -> Result<Vec<RgbImage>> {
    pair_video_from_files_clip(src, tgt, CLIP_METERS)
}

/// [`pair_video_from_files`] with another clip distance.
pub fn pair_video_from_files_clip<P: AsRef<Path> + Sync>(
    src: &[P],
    tgt: &[P],
    clip_m: f64,
) -> Result<Vec<RgbImage>> {
    let read = |ps: &[P]| -> Result<Vec<DepthImage>> {
        ps.par_iter().map(|p| read_depth_png(p.as_ref())).collect()
    };
    let s = read(src)?;
    let t = read(tgt)?;
    if let Some(first) = s.first().or(t.first()) {
        let all = src
            .iter()
            .map(|p| p.as_ref())
            .chain(tgt.iter().map(|p| p.as_ref()));
        for (d, p) in s.iter().chain(&t).zip(all) {
            if (d.width, d.height) != (first.width, first.height) {
                return Err(crate::Error::format(
                    p,
                    "image size",
                    format!("{}x{} like the first frame", first.width, first.height),
                    format!("{}x{}", d.width, d.height),
                ));
            }
        }
    }
    Ok(build_pair_video_clip(&s, &t, clip_m))
}

/// The reference's 3DMatch video name (§1.3):
/// `{idx:06}_{scene}-{seq_src}_{frameid_src}@{seq_tgt}_{frameid_tgt}.mp4`, where a frame id is
/// the depth file name up to its first '.' (`frame-000000.depth.png` -> `frame-000000`).
pub fn reference_video_name_3dmatch(
    idx: usize,
    scene: &str,
    seq_src: &str,
    src_frame_file: &str,
    seq_tgt: &str,
    tgt_frame_file: &str,
) -> String {
    let id = |f: &str| f.split('.').next().unwrap_or(f).to_string();
    format!(
        "{idx:06}_{scene}-{seq_src}_{}@{seq_tgt}_{}.mp4",
        id(src_frame_file),
        id(tgt_frame_file)
    )
}

/// The metadata index a reference video name starts with (the text before the first '_').
pub fn reference_video_index(file_name: &str) -> Option<usize> {
    let stem = Path::new(file_name).file_name()?.to_str()?;
    let (head, _) = stem.split_once('_')?;
    head.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, data: Vec<u16>) -> DepthImage {
        DepthImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn hand_computed_pixels() {
        // 1 m, 2 m, 4 m, 8 m (clipped to 4 m), 0 (invalid), 65535 (invalid).
        let d = img(3, 2, vec![1000, 2000, 4000, 8000, 0, 65535]);
        let g = encode_depth_frame(&d);
        // inv: 1, 0.5, 0.25, 0.25 -> min 0.25, max 1 (up to 1e-8 terms).
        // 1 m: 0.75 / (0.75 + 1e-8) * 255 = 254.9999966 -> 254 (truncation).
        // 2 m: 0.25 / 0.75 * 255 = 84.99999887 -> 84.
        assert_eq!(g.as_raw(), &vec![254, 84, 0, 0, 0, 0]);
    }

    #[test]
    fn truncation_not_rounding() {
        // inv 1/1.5 = 0.6667: n = (0.6667 - 0.5)/(1 - 0.5) = 0.3333 -> 84.99 -> 84 (rounding
        // would give 85). 1 m -> 254, 2 m -> 0.
        let d = img(3, 1, vec![1000, 1500, 2000]);
        let g = encode_depth_frame(&d);
        assert_eq!(g.as_raw(), &vec![254, 84, 0]);
        // 1.2 m: inv 0.8333; n = 0.3333/0.5 = 0.6667 -> 169.99 -> 169.
        let d = img(3, 1, vec![1000, 1200, 2000]);
        assert_eq!(encode_depth_frame(&d).as_raw(), &vec![254, 169, 0]);
    }

    #[test]
    fn all_invalid_and_single_valid() {
        let d = img(2, 2, vec![0, 65535, 0, 0]);
        assert!(encode_depth_frame(&d).as_raw().iter().all(|&v| v == 0));
        // One valid pixel: max == min, n = 0 / 1e-8 = 0.
        let d = img(2, 1, vec![0, 1234]);
        assert_eq!(encode_depth_frame(&d).as_raw(), &vec![0, 0]);
    }

    #[test]
    fn pair_video_order_and_channels() {
        let a = img(2, 1, vec![1000, 2000]);
        let b = img(2, 1, vec![2000, 1000]);
        let v = build_pair_video(&[a.clone(), a], std::slice::from_ref(&b));
        assert_eq!(v.len(), 3);
        assert_eq!(v[0].as_raw(), &vec![254, 254, 254, 0, 0, 0]);
        assert_eq!(v[2].as_raw(), &vec![0, 0, 0, 254, 254, 254]);
    }

    #[test]
    fn video_names() {
        let n = reference_video_name_3dmatch(
            0,
            "7-scenes-redkitchen",
            "seq-01",
            "frame-000000.depth.png",
            "seq-01",
            "frame-000050.depth.png",
        );
        assert_eq!(
            n,
            "000000_7-scenes-redkitchen-seq-01_frame-000000@seq-01_frame-000050.mp4"
        );
        assert_eq!(reference_video_index(&n), Some(0));
        assert_eq!(
            reference_video_index("/a/b/001622_x-seq_f@s_g.mp4"),
            Some(1622)
        );
        assert_eq!(reference_video_index("video.mp4"), None);
    }
}
