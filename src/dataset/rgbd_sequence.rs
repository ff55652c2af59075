//! The 7-Scenes / 3DMatch raw RGB-D sequence layout:
//! `camera-intrinsics.txt` (3x3 K) and `frame-XXXXXX.{color.jpg|color.png, depth.png, pose.txt}`.
//! Depth: 16-bit PNG in mm (0 and 65535 invalid). Pose: camera-to-world, p_world = P * p_cam.

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use nalgebra::Isometry3;
use std::path::{Path, PathBuf};

#[derive(Clone, Debug)]
pub struct SequenceFrame {
    pub index: usize,
    pub depth: PathBuf,
    pub color: Option<PathBuf>,
    pub pose: Option<PathBuf>,
}

#[derive(Clone, Debug)]
pub struct RgbdSequence {
    pub dir: PathBuf,
    pub intrinsics_path: PathBuf,
    /// Frames sorted by index; indices need not be contiguous.
    pub frames: Vec<SequenceFrame>,
}

impl RgbdSequence {
    pub fn open(dir: &Path) -> Result<RgbdSequence> {
        let intrinsics_path = dir.join("camera-intrinsics.txt");
        if !intrinsics_path.is_file() {
            return Err(Error::format(
                dir,
                "camera-intrinsics.txt",
                "an RGB-D sequence folder with camera-intrinsics.txt",
                "no such file",
            ));
        }
        let rd = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
        let mut frames = Vec::new();
        for ent in rd {
            let ent = ent.map_err(|e| Error::io(dir, e))?;
            let name = ent.file_name().to_string_lossy().into_owned();
            let Some(rest) = name.strip_prefix("frame-") else {
                continue;
            };
            let Some(num) = rest.strip_suffix(".depth.png") else {
                continue;
            };
            let Ok(index) = num.parse::<usize>() else {
                continue;
            };
            let stem = format!("frame-{num}");
            let color = ["color.jpg", "color.png"]
                .iter()
                .map(|ext| dir.join(format!("{stem}.{ext}")))
                .find(|p| p.is_file());
            let pose = Some(dir.join(format!("{stem}.pose.txt"))).filter(|p| p.is_file());
            frames.push(SequenceFrame {
                index,
                depth: ent.path(),
                color,
                pose,
            });
        }
        if frames.is_empty() {
            return Err(Error::format(
                dir,
                "frames",
                "frame-XXXXXX.depth.png files",
                "none",
            ));
        }
        frames.sort_by_key(|f| f.index);
        Ok(RgbdSequence {
            dir: dir.to_path_buf(),
            intrinsics_path,
            frames,
        })
    }

    pub fn frame(&self, index: usize) -> Option<&SequenceFrame> {
        self.frames
            .binary_search_by_key(&index, |f| f.index)
            .ok()
            .map(|i| &self.frames[i])
    }

    /// Intrinsics; the image size is taken from the first depth frame.
    pub fn intrinsics(&self) -> Result<Intrinsics> {
        let d = crate::io::depth_png::read_depth_png(&self.frames[0].depth)?;
        crate::camera::camera_txt::read_intrinsics(&self.intrinsics_path, d.width, d.height)
    }

    /// Camera-to-world pose of a frame.
    pub fn world_from_camera(&self, index: usize) -> Result<Isometry3<f64>> {
        let f = self
            .frame(index)
            .ok_or_else(|| Error::Missing(format!("{}: no frame {index}", self.dir.display())))?;
        let p = f.pose.as_ref().ok_or_else(|| {
            Error::format(
                &f.depth,
                "pose",
                format!("frame-{index:06}.pose.txt next to it"),
                "missing",
            )
        })?;
        crate::camera::camera_txt::read_pose(p)
    }
}
