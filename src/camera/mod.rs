//! Camera models: pinhole (RGB-D sensors) and f-theta (LiDAR virtual camera), projection,
//! back-projection and depth rendering from point clouds.

pub mod camera_txt;
pub mod ftheta;
pub mod render;
pub mod sensor_origin;
pub mod trajectory;
pub mod visibility;

/// A posed depth view (camera, pose, depth image): what the lift and the visibility check read.
pub use visibility::DepthView;

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

/// The camera a set of depth frames was taken (or rendered) with.
///
/// Depth convention differs by model: a pinhole depth image stores z along the optical axis,
/// an f-theta one stores the range along each pixel's ray (both in millimetres).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "kebab-case")]
pub enum CameraModel {
    Pinhole(Intrinsics),
    FTheta(ftheta::FThetaCamera),
}

impl From<Intrinsics> for CameraModel {
    fn from(k: Intrinsics) -> Self {
        CameraModel::Pinhole(k)
    }
}

impl CameraModel {
    pub fn size(&self) -> (u32, u32) {
        match self {
            CameraModel::Pinhole(k) => (k.width, k.height),
            CameraModel::FTheta(c) => (c.width, c.height),
        }
    }

    /// "pinhole" or "f-theta", for labels.
    pub fn name(&self) -> &'static str {
        match self {
            CameraModel::Pinhole(_) => "pinhole",
            CameraModel::FTheta(_) => "f-theta",
        }
    }

    pub fn as_pinhole(&self) -> Option<&Intrinsics> {
        match self {
            CameraModel::Pinhole(k) => Some(k),
            CameraModel::FTheta(_) => None,
        }
    }

    /// Camera-frame point of pixel (u, v) with depth value `depth` (metres, in this model's
    /// convention: z for a pinhole, range for f-theta). None where f-theta has no ray.
    pub fn backproject(&self, u: f64, v: f64, depth: f64) -> Option<nalgebra::Point3<f64>> {
        match self {
            CameraModel::Pinhole(k) => Some(k.backproject(u, v, depth)),
            CameraModel::FTheta(c) => c.unproject(u, v).map(|d| nalgebra::Point3::from(d * depth)),
        }
    }

    /// Pixel of a camera-frame point; None where it is not imaged (behind a pinhole, beyond
    /// the f-theta max angle). The pixel may lie outside the image.
    pub fn project(&self, p: &nalgebra::Point3<f64>) -> Option<(f64, f64)> {
        match self {
            CameraModel::Pinhole(k) => k.project(p),
            CameraModel::FTheta(c) => c.project(p),
        }
    }

    /// The depth value this model stores for a camera-frame point (z or range), metres.
    pub fn depth_of(&self, p: &nalgebra::Point3<f64>) -> f64 {
        match self {
            CameraModel::Pinhole(_) => p.z,
            CameraModel::FTheta(_) => p.coords.norm(),
        }
    }

    /// Depth image (mm, this model's convention) of `points` seen with pose `camera_from_scan`.
    pub fn render_depth(
        &self,
        points: &[nalgebra::Point3<f32>],
        camera_from_scan: &nalgebra::Isometry3<f64>,
    ) -> crate::io::depth_png::DepthImage {
        match self {
            CameraModel::Pinhole(k) => render::render_depth(points, k, camera_from_scan),
            CameraModel::FTheta(c) => ftheta::render_depth_ftheta(points, c, camera_from_scan),
        }
    }

    /// For each point: imaged and not hidden behind nearer points.
    pub fn visibility(
        &self,
        points: &[nalgebra::Point3<f32>],
        camera_from_scan: &nalgebra::Isometry3<f64>,
    ) -> Vec<bool> {
        let opts = render::SplatOptions::default();
        match self {
            CameraModel::Pinhole(k) => {
                render::visibility_pinhole(points, k, camera_from_scan, &opts)
            }
            CameraModel::FTheta(c) => c.visibility(points, camera_from_scan, &opts),
        }
    }

    /// Frustum for display at `range` metres (the curved border of a wide f-theta image is
    /// sampled; a pinhole border is its four edges).
    pub fn frustum(
        &self,
        camera_from_scan: &nalgebra::Isometry3<f64>,
        range: f64,
    ) -> render::Frustum {
        match self {
            CameraModel::Pinhole(k) => render::pinhole_frustum(k, camera_from_scan, range),
            CameraModel::FTheta(c) => c.frustum(camera_from_scan, range, 16),
        }
    }

    /// The parameters that define the model, for cache keys.
    pub fn key(&self) -> serde_json::Value {
        match self {
            // The pinhole key keeps the layout older cache entries were written with.
            CameraModel::Pinhole(k) => {
                serde_json::json!([k.fx, k.fy, k.cx, k.cy, k.width as f64, k.height as f64])
            }
            CameraModel::FTheta(c) => serde_json::json!({
                "f-theta": [c.width, c.height], "c": [c.cx, c.cy], "poly": c.poly,
                "max_angle": c.max_angle,
            }),
        }
    }
}
