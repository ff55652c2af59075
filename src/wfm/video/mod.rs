//! Video files: H.264 mp4 writing and reading (bundled OpenH264 codec + the `mp4` muxer), and
//! folders of PNG frames.
//!
//! - Writing: frames are converted to YUV 4:2:0 with BT.601 limited-range coefficients (what
//!   ffmpeg and OpenCV assume for an untagged stream), encoded by OpenH264 (constrained
//!   baseline, one IDR every 30 frames, no frame skipping) and muxed into an ISO-BMFF `avc1`
//!   track at a fixed frame rate (30 fps for depth videos). ffmpeg, imageio and Cosmos decode it.
//! - Reading: only H.264 (`avc1`/`avc3`) video tracks; anything else (e.g. the reference's own
//!   `mp4v` MPEG-4 Part 2 depth videos) is a clear error naming the file and the codec found.
//!   Frames come back in display order as RGB, BT.601 limited range, nearest chroma upsampling.
//!   Cosmos writes libx264 yuv420p (High profile, B-frames), which the OpenH264 decoder reads.
//! - PNG folders: `frame_000000.png`, `frame_000001.png`, ... (8-bit RGB).

mod read;

use read::split_annexb;
pub use read::{
    decode_annexb, decode_h264_samples, decode_mp4_frames, h264_access_units, probe_mp4,
    read_mp4_frames, VideoInfo,
};

use crate::error::{Error, Result};
use crate::io::output::write_atomic;
use image::RgbImage;
use openh264::encoder::{
    BitRate, Encoder, EncoderConfig, FrameRate, IntraFramePeriod, QpRange, RateControlMode,
};
use openh264::formats::{YUVBuffer, YUVSource};
use openh264::OpenH264API;
use std::io::Cursor;
use std::path::{Path, PathBuf};

// ------------------------------------------------------------------------------------------
// Writing
// ------------------------------------------------------------------------------------------

/// Encode `frames` (all the same even width and height) as an H.264 mp4 at `fps`; the file is
/// written atomically.
pub fn write_mp4_h264(path: &Path, frames: &[RgbImage], fps: u32) -> Result<()> {
    let bytes = encode_mp4_h264(frames, fps).map_err(|e| match e {
        Error::Invalid(m) => Error::Invalid(format!("{}: {m}", path.display())),
        Error::Shape(m) => Error::Shape(format!("{}: {m}", path.display())),
        Error::Param(m) => Error::Param(format!("{}: {m}", path.display())),
        other => other,
    })?;
    write_atomic(path, &bytes)
}

/// The mp4 bytes `write_mp4_h264` would write.
pub fn encode_mp4_h264(frames: &[RgbImage], fps: u32) -> Result<Vec<u8>> {
    let first = frames
        .first()
        .ok_or_else(|| Error::Invalid("cannot write a video with no frames".into()))?;
    let (w, h) = first.dimensions();
    if w == 0 || h == 0 || w % 2 != 0 || h % 2 != 0 || w > 3840 || h > 2160 {
        return Err(Error::Shape(format!(
            "H.264 frames must have even width and height up to 3840x2160, found {w}x{h}"
        )));
    }
    if fps == 0 {
        return Err(Error::Param("frame rate must be positive".into()));
    }
    if let Some((i, f)) = frames
        .iter()
        .enumerate()
        .find(|(_, f)| f.dimensions() != (w, h))
    {
        return Err(Error::Shape(format!(
            "frame {i} is {}x{}, expected {w}x{h} like frame 0",
            f.width(),
            f.height()
        )));
    }
    let ext = |m: String| Error::External {
        what: "OpenH264 encoder".into(),
        message: m,
    };
    // A generous bitrate: control videos must keep their grey levels (about 45 dB on depth).
    let bps = (w as u64 * h as u64 * fps as u64 * 2).min(u32::MAX as u64) as u32;
    let config = EncoderConfig::new()
        .max_frame_rate(FrameRate::from_hz(fps as f32))
        .rate_control_mode(RateControlMode::Bitrate)
        .bitrate(BitRate::from_bps(bps))
        .qp(QpRange::new(0, 32))
        .skip_frames(false)
        .intra_frame_period(IntraFramePeriod::from_num_frames(fps))
        .num_threads(1);
    let mut encoder = Encoder::with_api_config(OpenH264API::from_source(), config)
        .map_err(|e| ext(e.to_string()))?;

    let mut sps: Option<Vec<u8>> = None;
    let mut pps: Option<Vec<u8>> = None;
    let mut samples: Vec<(Vec<u8>, bool)> = Vec::with_capacity(frames.len());
    let mut yuv = vec![0u8; (w * h * 3 / 2) as usize];
    for (i, frame) in frames.iter().enumerate() {
        rgb_to_i420(frame, &mut yuv);
        let buf = YUVBuffer::from_vec(std::mem::take(&mut yuv), w as usize, h as usize);
        let stream = encoder
            .encode(&buf)
            .map_err(|e| ext(format!("frame {i}: {e}")))?;
        let annexb = stream.to_vec();
        yuv = buf_into_vec(buf);
        let mut sample = Vec::with_capacity(annexb.len() + 16);
        let mut is_sync = false;
        for nal in split_annexb(&annexb) {
            match nal.first().map(|b| b & 0x1f) {
                Some(7) => sps = sps.or_else(|| Some(nal.to_vec())),
                Some(8) => pps = pps.or_else(|| Some(nal.to_vec())),
                Some(t) => {
                    is_sync |= t == 5;
                    sample.extend_from_slice(&(nal.len() as u32).to_be_bytes());
                    sample.extend_from_slice(nal);
                }
                None => {}
            }
        }
        if sample.is_empty() {
            return Err(ext(format!("frame {i}: the encoder produced no picture")));
        }
        samples.push((sample, is_sync));
    }
    let (Some(sps), Some(pps)) = (sps, pps) else {
        return Err(ext("no SPS/PPS in the encoded stream".into()));
    };

    let mp4_err = |e: mp4::Error| ext(format!("mp4 muxer: {e}"));
    let config = mp4::Mp4Config {
        major_brand: str::parse("isom").map_err(mp4_err)?,
        minor_version: 512,
        compatible_brands: ["isom", "iso2", "avc1", "mp41"]
            .iter()
            .map(|b| str::parse(b))
            .collect::<std::result::Result<_, _>>()
            .map_err(mp4_err)?,
        timescale: 1000,
    };
    let mut writer =
        mp4::Mp4Writer::write_start(Cursor::new(Vec::<u8>::new()), &config).map_err(mp4_err)?;
    // Track timescale: fps * 1000 ticks per second, 1000 ticks per frame (exact for integer fps).
    let timescale = fps * 1000;
    writer
        .add_track(&mp4::TrackConfig {
            track_type: mp4::TrackType::Video,
            timescale,
            language: "und".into(),
            media_conf: mp4::MediaConfig::AvcConfig(mp4::AvcConfig {
                width: w as u16,
                height: h as u16,
                seq_param_set: sps,
                pic_param_set: pps,
            }),
        })
        .map_err(mp4_err)?;
    for (i, (bytes, is_sync)) in samples.into_iter().enumerate() {
        writer
            .write_sample(
                1,
                &mp4::Mp4Sample {
                    start_time: i as u64 * 1000,
                    duration: 1000,
                    rendering_offset: 0,
                    is_sync,
                    bytes: mp4::Bytes::from(bytes),
                },
            )
            .map_err(mp4_err)?;
    }
    writer.write_end().map_err(mp4_err)?;
    Ok(writer.into_writer().into_inner())
}

fn buf_into_vec(buf: YUVBuffer) -> Vec<u8> {
    // YUVBuffer has no into_inner; copy the planes back (cheap next to encoding).
    let mut v = Vec::with_capacity(buf.y().len() + buf.u().len() + buf.v().len());
    v.extend_from_slice(buf.y());
    v.extend_from_slice(buf.u());
    v.extend_from_slice(buf.v());
    v
}

/// RGB -> I420, BT.601 limited range, rounded; chroma from the 2x2 average.
fn rgb_to_i420(img: &RgbImage, out: &mut [u8]) {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let (ys, rest) = out.split_at_mut(w * h);
    let (us, vs) = rest.split_at_mut(w * h / 4);
    let px = img.as_raw();
    for (i, y) in ys.iter_mut().enumerate() {
        let (r, g, b) = (px[3 * i] as f32, px[3 * i + 1] as f32, px[3 * i + 2] as f32);
        *y = (16.0 + 0.256_789 * r + 0.504_129 * g + 0.097_906 * b + 0.5) as u8;
    }
    let cw = w / 2;
    for cy in 0..h / 2 {
        for cx in 0..cw {
            let (mut r, mut g, mut b) = (0.0f32, 0.0f32, 0.0f32);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let i = 3 * ((2 * cy + dy) * w + 2 * cx + dx);
                r += px[i] as f32;
                g += px[i + 1] as f32;
                b += px[i + 2] as f32;
            }
            let (r, g, b) = (r / 4.0, g / 4.0, b / 4.0);
            let u = 128.0 - 0.148_223 * r - 0.290_993 * g + 0.439_216 * b;
            let v = 128.0 + 0.439_216 * r - 0.367_788 * g - 0.071_427 * b;
            us[cy * cw + cx] = (u + 0.5).clamp(0.0, 255.0) as u8;
            vs[cy * cw + cx] = (v + 0.5).clamp(0.0, 255.0) as u8;
        }
    }
}

// ------------------------------------------------------------------------------------------
// PNG frame folders
// ------------------------------------------------------------------------------------------

/// File name of frame `i` in a PNG frame folder.
pub fn frame_file_name(i: usize) -> String {
    format!("frame_{i:06}.png")
}

/// Write `frames` as `dir/frame_000000.png`, ... (atomic per file); returns the paths.
pub fn write_png_frames(dir: &Path, frames: &[RgbImage]) -> Result<Vec<PathBuf>> {
    use rayon::prelude::*;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| {
            let p = dir.join(frame_file_name(i));
            let mut bytes = Vec::new();
            f.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)
                .map_err(|e| Error::External {
                    what: format!("png encoder for {}", p.display()),
                    message: e.to_string(),
                })?;
            write_atomic(&p, &bytes)?;
            Ok(p)
        })
        .collect()
}

/// Read a PNG frame folder written by `write_png_frames`: frames 0, 1, ... until the first
/// missing index. An empty folder, or frames of different sizes, is an error.
pub fn read_png_frames(dir: &Path) -> Result<Vec<RgbImage>> {
    use rayon::prelude::*;
    if !dir.is_dir() {
        return Err(Error::format(
            dir,
            "folder",
            "a folder of frame_NNNNNN.png files",
            "no such folder",
        ));
    }
    let mut paths = Vec::new();
    while dir.join(frame_file_name(paths.len())).is_file() {
        paths.push(dir.join(frame_file_name(paths.len())));
    }
    if paths.is_empty() {
        return Err(Error::format(
            dir,
            frame_file_name(0),
            "frame_000000.png, frame_000001.png, ...",
            "no frame files",
        ));
    }
    let frames: Vec<RgbImage> = paths
        .par_iter()
        .map(|p| {
            let bytes = crate::io::limits::read_file(p)?;
            crate::io::depth_png::decode_image(p, &bytes, image::ImageFormat::Png)
                .map(|i| i.to_rgb8())
        })
        .collect::<Result<_>>()?;
    let d = frames[0].dimensions();
    if let Some((i, f)) = frames.iter().enumerate().find(|(_, f)| f.dimensions() != d) {
        return Err(Error::format(
            &paths[i],
            "image size",
            format!("{}x{} like frame 0", d.0, d.1),
            format!("{}x{}", f.width(), f.height()),
        ));
    }
    Ok(frames)
}

/// Read frames from either an mp4 file or a PNG frame folder.
pub fn read_frames(path: &Path) -> Result<Vec<RgbImage>> {
    if path.is_dir() {
        read_png_frames(path)
    } else {
        read_mp4_frames(path)
    }
}

/// Peak signal-to-noise ratio (dB) between two images of the same size; infinite when equal.
pub fn psnr(a: &RgbImage, b: &RgbImage) -> Result<f64> {
    if a.dimensions() != b.dimensions() {
        return Err(Error::Shape(format!(
            "psnr of images of different sizes: {:?} vs {:?}",
            a.dimensions(),
            b.dimensions()
        )));
    }
    let se: f64 = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum();
    let mse = se / a.as_raw().len().max(1) as f64;
    Ok(if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_frames(n: usize, w: u32, h: u32) -> Vec<RgbImage> {
        (0..n)
            .map(|t| {
                RgbImage::from_fn(w, h, |x, y| {
                    // Smooth moving gradients: compressible and easy to compare.
                    let r = (x * 200 / w + 2 * t as u32) as u8;
                    let g = (y * 200 / h + t as u32) as u8;
                    let b = (40 + (x + y) * 100 / (w + h) + 3 * t as u32) as u8;
                    image::Rgb([r, g, b])
                })
            })
            .collect()
    }

    #[test]
    fn own_roundtrip_in_process() {
        let frames = test_frames(12, 96, 64);
        let bytes = encode_mp4_h264(&frames, 30).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v.mp4");
        std::fs::write(&p, bytes).unwrap();
        let info = probe_mp4(&p).unwrap();
        assert_eq!(info.codec, "avc1");
        assert_eq!((info.width, info.height, info.frame_count), (96, 64, 12));
        assert!((info.fps - 30.0).abs() < 1e-6, "fps {}", info.fps);
        let back = read_mp4_frames(&p).unwrap();
        assert_eq!(back.len(), 12);
        for (a, b) in frames.iter().zip(&back) {
            let q = psnr(a, b).unwrap();
            assert!(q > 35.0, "psnr {q}");
        }
    }

    #[test]
    fn odd_sizes_and_empty_are_errors() {
        assert!(encode_mp4_h264(&[], 30).is_err());
        assert!(encode_mp4_h264(&test_frames(1, 33, 16), 30).is_err());
        let mut fs = test_frames(2, 32, 16);
        fs[1] = RgbImage::new(16, 16);
        let e = encode_mp4_h264(&fs, 30).unwrap_err().to_string();
        assert!(e.contains("frame 1"), "{e}");
    }

    #[test]
    fn annexb_split() {
        let s = [
            0, 0, 0, 1, 0x67, 1, 2, 0, 0, 1, 0x68, 3, 0, 0, 0, 1, 0x65, 9,
        ];
        let n = split_annexb(&s);
        assert_eq!(n, vec![&[0x67, 1, 2][..], &[0x68, 3][..], &[0x65, 9][..]]);
    }

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.mp4");
        std::fs::write(
            &p,
            b"\x00\x00\x00\x18ftypisom\x00\x00\x02\x00isomiso2garbage",
        )
        .unwrap();
        let e = read_mp4_frames(&p).unwrap_err().to_string();
        assert!(e.contains("bad.mp4"), "{e}");
        let e = read_mp4_frames(&dir.path().join("none.mp4"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.mp4"), "{e}");
    }

    #[test]
    fn png_folder_roundtrip() {
        let frames = test_frames(3, 20, 10);
        let dir = tempfile::tempdir().unwrap();
        let paths = write_png_frames(dir.path(), &frames).unwrap();
        assert_eq!(paths.len(), 3);
        assert_eq!(read_png_frames(dir.path()).unwrap(), frames);
        let empty = tempfile::tempdir().unwrap();
        assert!(read_png_frames(empty.path()).is_err());
    }
}
