//! Camera models: pinhole (RGB-D sensors) and f-theta (LiDAR virtual camera), projection,
//! back-projection and depth rendering from point clouds.

pub mod ftheta;
pub mod render;
pub mod trajectory;

use serde::{Deserialize, Serialize};

/// Pinhole intrinsics in pixels for an image of `width` x `height`.
/// Projection: u = fx * x / z + cx, v = fy * y / z + cy (OpenCV axes).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Back-project pixel (u, v) with depth z (metres, along the optical axis).
    pub fn backproject(&self, u: f64, v: f64, z: f64) -> nalgebra::Point3<f64> {
        nalgebra::Point3::new((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z)
    }
    /// Project a camera-frame point; None behind the camera.
    pub fn project(&self, p: &nalgebra::Point3<f64>) -> Option<(f64, f64)> {
        if p.z <= 0.0 {
            return None;
        }
        Some((self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }
}
