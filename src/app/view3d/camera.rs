//! The 3D panel's orbit camera (three-d's camera and orbit control) and the projection of
//! points to the viewport.

use nalgebra::Matrix4;

/// three-d's perspective camera driven by its [`three_d::OrbitControl`]. Clouds use OpenCV
/// axes (y down), so "up" is -y.
#[derive(Clone, Debug)]
pub struct SceneCamera {
    pub camera: three_d::Camera,
    pub control: three_d::OrbitControl,
    pub fov_y: f32,
}

impl Default for SceneCamera {
    fn default() -> Self {
        Self::looking_at([0.0, 0.0, 2.0], 4.0, 0.0, 0.35)
    }
}

impl SceneCamera {
    /// Orbiting `target` at `distance`, `yaw` about the up axis, `pitch` above the horizon.
    fn looking_at(target: [f32; 3], distance: f32, yaw: f32, pitch: f32) -> Self {
        let fov_y = 0.9f32;
        let t = three_d::vec3(target[0], target[1], target[2]);
        let (cp, sp) = (pitch.cos(), pitch.sin());
        let dir = three_d::vec3(cp * yaw.sin(), -sp, -cp * yaw.cos());
        let camera = three_d::Camera::new_perspective(
            three_d::Viewport::new_at_origo(1, 1),
            t + dir * distance,
            t,
            three_d::vec3(0.0, -1.0, 0.0),
            three_d::radians(fov_y),
            0.01,
            100.0,
        );
        let mut me = Self {
            camera,
            control: three_d::OrbitControl::new(t, 1e-3, 1e5),
            fov_y,
        };
        me.update_clip_planes();
        me
    }

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
        Self::looking_at(c, r / (0.9f32 / 2.0).tan() * 0.8, 0.35, 0.45)
    }

    pub fn distance(&self) -> f32 {
        use three_d::InnerSpace;
        (self.camera.position() - self.control.target).magnitude()
    }

    /// Near and far planes follow the distance (a room and a LiDAR sweep both stay sharp).
    fn update_clip_planes(&mut self) {
        let d = self.distance();
        self.camera.set_perspective_projection(
            three_d::radians(self.fov_y),
            (d * 0.01).max(1e-3),
            d * 20.0 + 10.0,
        );
    }

    fn event(&mut self, e: three_d::Event) {
        self.control.handle_events(&mut self.camera, &mut [e]);
        self.update_clip_planes();
    }

    /// A left drag of (`dx`, `dy`) pixels, through the orbit control.
    pub fn orbit(&mut self, dx: f32, dy: f32) {
        self.event(three_d::Event::MouseMotion {
            button: Some(three_d::MouseButton::Left),
            delta: (dx * 0.8, dy * 0.8),
            position: three_d::PhysicalPoint { x: 0.0, y: 0.0 },
            modifiers: three_d::Modifiers::default(),
            handled: false,
        });
    }

    /// Scroll by `scroll` points (egui's units), through the orbit control.
    pub fn zoom(&mut self, scroll: f32) {
        self.event(three_d::Event::MouseWheel {
            delta: (0.0, scroll * 0.25),
            position: three_d::PhysicalPoint { x: 0.0, y: 0.0 },
            modifiers: three_d::Modifiers::default(),
            handled: false,
        });
    }

    /// Moves the orbit centre in the image plane; `dx`, `dy` in pixels of a view `height`
    /// high (the orbit control has no pan).
    pub fn pan(&mut self, dx: f32, dy: f32, height: f32) {
        let scale = 2.0 * self.distance() * (self.fov_y / 2.0).tan() / height.max(1.0);
        let right = self.camera.right_direction();
        let up = self.camera.up_orthogonal();
        let change = -right * dx * scale + up * dy * scale;
        self.camera.translate(change);
        self.control.target += change;
    }

    /// Projection times view for a `w` x `h` viewport (column-major, OpenGL clip space).
    pub fn view_projection(&mut self, w: f32, h: f32) -> Matrix4<f32> {
        self.camera.set_viewport(three_d::Viewport::new_at_origo(
            w.max(1.0) as u32,
            h.max(1.0) as u32,
        ));
        let m = self.camera.projection() * self.camera.view();
        let a: &[f32; 16] = m.as_ref();
        Matrix4::from_column_slice(a)
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
        let mut cam = SceneCamera::framing([-1.0, -1.0, 1.0], [1.0, 1.0, 3.0]);
        let vp = cam.view_projection(300.0, 200.0);
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
    fn orbit_keeps_the_distance_pan_moves_the_centre_zoom_gets_closer() {
        let mut cam = SceneCamera::default();
        let d0 = cam.distance();
        let c0 = cam.control.target;
        cam.orbit(40.0, 10.0);
        assert!((cam.distance() - d0).abs() < 1e-3 * d0);
        assert_eq!(cam.control.target, c0);
        cam.pan(10.0, 0.0, 100.0);
        assert_ne!(cam.control.target, c0);
        assert!((cam.distance() - d0).abs() < 1e-3 * d0);
        // the orbit centre stays in the middle of the view after a pan
        let t = cam.control.target;
        let vp = cam.view_projection(200.0, 100.0);
        let p = project(&vp, [t.x, t.y, t.z], 200.0, 100.0).unwrap();
        assert!(
            (p[0] - 100.0).abs() < 0.05 && (p[1] - 50.0).abs() < 0.05,
            "{p:?}"
        );
        cam.zoom(100.0);
        assert!(cam.distance() < d0);
    }
}
