//! 16-bit depth PNGs in millimetres (7-Scenes, 3DMatch raw, ScanNet).
//!
//! Convention: value = depth along the optical axis (z) in mm. 0 means "no measurement";
//! 65535 also occurs in 7-Scenes and is treated as invalid too.

use crate::error::{Error, Result};
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    /// Row-major raw values in millimetres.
    pub data: Vec<u16>,
}

impl DepthImage {
    pub fn raw(&self, u: u32, v: u32) -> u16 {
        self.data[(v * self.width + u) as usize]
    }

    /// Depth in metres, None for invalid pixels (0 or 65535).
    pub fn meters(&self, u: u32, v: u32) -> Option<f32> {
        match self.raw(u, v) {
            0 | u16::MAX => None,
            d => Some(d as f32 / 1000.0),
        }
    }

    pub fn valid_count(&self) -> usize {
        self.data
            .iter()
            .filter(|&&d| d != 0 && d != u16::MAX)
            .count()
    }
}

pub fn read_depth_png(path: &Path) -> Result<DepthImage> {
    let bytes = crate::io::limits::read_file(path)?;
    parse_depth_png(path, &bytes)
}

/// Decode PNG bytes under the decoded-size limit; `path` is used only in error messages.
pub fn parse_depth_png(path: &Path, bytes: &[u8]) -> Result<DepthImage> {
    let img = decode_image(path, bytes, image::ImageFormat::Png)?;
    match img {
        image::DynamicImage::ImageLuma16(buf) => Ok(DepthImage {
            width: buf.width(),
            height: buf.height(),
            data: buf.into_raw(),
        }),
        other => Err(Error::format(
            path,
            "colour type",
            "16-bit single-channel (grey) depth in millimetres",
            format!("{:?}", other.color()),
        )),
    }
}

/// Decode an image, refusing one whose decoded pixels would exceed
/// [`crate::io::limits::max_decoded_bytes`] (a few-KB PNG can declare 65535 x 65535 pixels).
pub fn decode_image(
    path: &Path,
    bytes: &[u8],
    format: image::ImageFormat,
) -> Result<image::DynamicImage> {
    let max = crate::io::limits::max_decoded_bytes();
    let mut r = image::ImageReader::with_format(std::io::Cursor::new(bytes), format);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max);
    r.limits(limits);
    r.decode().map_err(|e| {
        let hint = match e {
            image::ImageError::Limits(_) => format!(
                " (over the {max}-byte decoded-size limit; raise {} if the image is real)",
                crate::io::limits::ENV_MAX_DECODED_BYTES
            ),
            _ => String::new(),
        };
        Error::format(
            path,
            "image",
            format!("a readable {format:?} image"),
            format!("{e}{hint}"),
        )
    })
}

/// Write a 16-bit depth PNG (millimetres, 0 = invalid).
pub fn write_depth_png(path: &Path, depth: &DepthImage) -> Result<()> {
    crate::io::output::write_atomic(path, &encode_depth_png(path, depth)?)
}

/// The bytes [`write_depth_png`] writes; `path` names the image in errors.
pub fn encode_depth_png(path: &Path, depth: &DepthImage) -> Result<Vec<u8>> {
    let buf = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
        depth.width,
        depth.height,
        depth.data.clone(),
    )
    .ok_or_else(|| Error::Shape(format!("depth image size mismatch for {}", path.display())))?;
    let mut out = Vec::new();
    image::DynamicImage::ImageLuma16(buf)
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .map_err(|e| Error::External {
            what: format!("png encoder for {}", path.display()),
            message: e.to_string(),
        })?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_and_invalid_values() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.png");
        let img = DepthImage {
            width: 3,
            height: 2,
            data: vec![0, 1000, 65535, 2500, 1, 4000],
        };
        write_depth_png(&p, &img).unwrap();
        let back = read_depth_png(&p).unwrap();
        assert_eq!(back, img);
        assert_eq!(back.meters(0, 0), None);
        assert_eq!(back.meters(2, 0), None);
        assert_eq!(back.meters(1, 0), Some(1.0));
        assert_eq!(back.valid_count(), 4);
    }

    #[test]
    fn rejects_colour_png() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.png");
        image::RgbImage::new(4, 4).save(&p).unwrap();
        let err = read_depth_png(&p).unwrap_err().to_string();
        assert!(err.contains("c.png") && err.contains("16-bit"), "{err}");
    }
}
