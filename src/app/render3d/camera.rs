//! Orbit camera for the 3D panel. Clouds use OpenCV axes (y down), so "up" is -y.

use nalgebra::{Matrix4, Perspective3, Point3, Vector3};

#[derive(Clone, Debug, PartialEq)]
pub struct OrbitCamera {
    pub target: [f32; 3],
    /// Rotation about the up axis, radians.
    pub yaw: f32,
    /// Elevation, radians (positive looks down on the scene).
    pub pitch: f32,
    pub distance: f32,
    pub fov_y: f32,
}

impl Default for OrbitCamera {
    fn default() -> Self {
        Self {
            target: [0.0, 0.0, 2.0],
            yaw: 0.0,
            pitch: 0.35,
            distance: 4.0,
            fov_y: 0.9,
        }
    }
}

impl OrbitCamera {
    /// Frames an axis-aligned box, seen from behind the scan origin (-z) and slightly above.
    pub fn framing(lo: [f32; 3], hi: [f32; 3]) -> Self {
        let c = [
            (lo[0] + hi[0]) / 2.0,
            (lo[1] + hi[1]) / 2.0,
            (lo[2] + hi[2]) / 2.0,
        ];
        let r = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2))
            .sqrt()
            .max(1e-3)
            / 2.0;
        let fov_y: f32 = 0.9;
        Self {
            target: c,
            yaw: 0.35,
            pitch: 0.45,
            distance: r / (fov_y / 2.0).tan() * 0.8,
            fov_y,
        }
    }

    pub fn eye(&self) -> Point3<f32> {
        let (cp, sp) = (self.pitch.cos(), self.pitch.sin());
        let dir = Vector3::new(cp * self.yaw.sin(), -sp, -cp * self.yaw.cos());
        Point3::from(Vector3::from(self.target) + dir * self.distance)
    }

    fn up() -> Vector3<f32> {
        Vector3::new(0.0, -1.0, 0.0)
    }

    pub fn view(&self) -> Matrix4<f32> {
        Matrix4::look_at_rh(&self.eye(), &Point3::from(self.target), &Self::up())
    }

    pub fn projection(&self, aspect: f32) -> Matrix4<f32> {
        let near = (self.distance * 0.01).max(1e-3);
        let far = self.distance * 20.0 + 10.0;
        Perspective3::new(aspect.max(1e-3), self.fov_y, near, far).to_homogeneous()
    }

    pub fn view_projection(&self, aspect: f32) -> Matrix4<f32> {
        self.projection(aspect) * self.view()
    }

    pub fn orbit(&mut self, dx: f32, dy: f32) {
        self.yaw += dx * 0.008;
        self.pitch = (self.pitch + dy * 0.008).clamp(-1.55, 1.55);
    }

    /// Moves the orbit centre in the image plane; `dx`, `dy` in pixels of a view `height` high.
    pub fn pan(&mut self, dx: f32, dy: f32, height: f32) {
        let v = self.view();
        let right = Vector3::new(v[(0, 0)], v[(0, 1)], v[(0, 2)]);
        let up = Vector3::new(v[(1, 0)], v[(1, 1)], v[(1, 2)]);
        let scale = 2.0 * self.distance * (self.fov_y / 2.0).tan() / height.max(1.0);
        let t = Vector3::from(self.target) - right * dx * scale + up * dy * scale;
        self.target = [t.x, t.y, t.z];
    }

    pub fn zoom(&mut self, scroll: f32) {
        self.distance = (self.distance * (-scroll * 0.0025).exp()).clamp(1e-3, 1e5);
    }
}

/// Projects a point with a view-projection matrix into pixel coordinates of a `w` x `h`
/// viewport (origin top-left). None behind the camera.
pub fn project(vp: &Matrix4<f32>, p: [f32; 3], w: f32, h: f32) -> Option<[f32; 2]> {
    let c = vp * nalgebra::Vector4::new(p[0], p[1], p[2], 1.0);
    if c.w <= 1e-6 {
        return None;
    }
    let (x, y) = (c.x / c.w, c.y / c.w);
    Some([(x + 1.0) * 0.5 * w, (1.0 - y) * 0.5 * h])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_puts_the_box_centre_in_the_middle_and_inside() {
        let cam = OrbitCamera::framing([-1.0, -1.0, 1.0], [1.0, 1.0, 3.0]);
        let vp = cam.view_projection(1.5);
        let c = project(&vp, [0.0, 0.0, 2.0], 300.0, 200.0).unwrap();
        assert!(
            (c[0] - 150.0).abs() < 1e-2 && (c[1] - 100.0).abs() < 1e-2,
            "{c:?}"
        );
        for corner in [[-1.0, -1.0, 1.0], [1.0, 1.0, 3.0], [1.0, -1.0, 1.0]] {
            let p = project(&vp, corner, 300.0, 200.0).unwrap();
            assert!(
                p[0] > 0.0 && p[0] < 300.0 && p[1] > 0.0 && p[1] < 200.0,
                "{p:?}"
            );
        }
        // -y is up: a point above the centre projects above it on screen
        let above = project(&vp, [0.0, -0.5, 2.0], 300.0, 200.0).unwrap();
        assert!(above[1] < c[1]);
    }

    #[test]
    fn pan_moves_target_and_zoom_changes_distance() {
        let mut cam = OrbitCamera::default();
        let t0 = cam.target;
        cam.pan(10.0, 0.0, 100.0);
        assert_ne!(cam.target, t0);
        let d0 = cam.distance;
        cam.zoom(100.0);
        assert!(cam.distance < d0);
    }
}
