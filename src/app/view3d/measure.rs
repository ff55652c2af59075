//! The distance tool: two points picked in the 3D view (of either cloud) and the distance
//! between them, in metres, in the target's frame.
//!
//! A source point sits where the drawn pose puts it (`target_from_source`, without the
//! side-by-side shift, which is only a display offset): two points of one cloud measure the
//! same under any pose; a source point and a target point measure the residual between them
//! under that pose.

use nalgebra::{Isometry3, Point3};

use crate::app::model::InspectorModel;

/// Which cloud a picked point belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cloud {
    Source,
    Target,
}

impl Cloud {
    pub fn label(self) -> &'static str {
        match self {
            Self::Source => "source",
            Self::Target => "target",
        }
    }
}

/// A picked point: its cloud and its index there.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Picked {
    pub cloud: Cloud,
    pub index: usize,
}

/// The tool's state: whether clicks measure (instead of selecting), and the ends picked so far.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Measure {
    pub active: bool,
    /// At most two: the ends of the measurement, in the order they were picked.
    pub picked: Vec<Picked>,
}

impl Measure {
    /// A click on a point: the first two clicks are the ends; a third starts a new measurement.
    pub fn pick(&mut self, p: Picked) {
        if self.picked.len() >= 2 {
            self.picked.clear();
        }
        self.picked.push(p);
    }

    /// Forgets the picked ends (a new pair, or the tool switched off: indices would name other
    /// points of other clouds).
    pub fn clear(&mut self) {
        self.picked.clear();
    }
}

/// A finished measurement, in the target's frame (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measurement {
    pub a: Picked,
    pub b: Picked,
    pub a_xyz: [f64; 3],
    pub b_xyz: [f64; 3],
    pub distance_m: f64,
}

impl Measurement {
    /// `b - a` per axis (metres).
    pub fn delta(&self) -> [f64; 3] {
        [
            self.b_xyz[0] - self.a_xyz[0],
            self.b_xyz[1] - self.a_xyz[1],
            self.b_xyz[2] - self.a_xyz[2],
        ]
    }

    /// The readout: both ends, the distance and its components; a source-target distance
    /// depends on the pose, and says so.
    pub fn text(&self, pose_label: &str) -> String {
        let d = self.delta();
        let under = if self.a.cloud != self.b.cloud {
            format!(" under the {pose_label}")
        } else {
            String::new()
        };
        format!(
            "{} {} -> {} {}: {}{under}\nΔx {:+.3} m · Δy {:+.3} m · Δz {:+.3} m",
            self.a.cloud.label(),
            self.a.index,
            self.b.cloud.label(),
            self.b.index,
            format_distance(self.distance_m),
            d[0],
            d[1],
            d[2],
        )
    }
}

/// Metres with three decimals, and centimetres beside them under a metre.
pub fn format_distance(m: f64) -> String {
    if m < 1.0 {
        format!("{m:.3} m ({:.1} cm)", m * 100.0)
    } else {
        format!("{m:.3} m")
    }
}

/// Where a picked point is in the target's frame: a source point under `target_from_source`,
/// a target point as it is. None for an index the clouds do not have.
pub fn position(
    model: &InspectorModel,
    target_from_source: &Isometry3<f64>,
    p: Picked,
) -> Option<[f64; 3]> {
    let to64 = |q: &[f32; 3]| Point3::new(q[0] as f64, q[1] as f64, q[2] as f64);
    let q = match p.cloud {
        Cloud::Source => target_from_source * to64(model.source.get(p.index)?),
        Cloud::Target => to64(model.target.get(p.index)?),
    };
    Some([q.x, q.y, q.z])
}

/// The measurement between the two picked ends, once there are two.
pub fn measurement(
    model: &InspectorModel,
    target_from_source: &Isometry3<f64>,
    measure: &Measure,
) -> Option<Measurement> {
    let [a, b] = measure.picked.as_slice() else {
        return None;
    };
    let a_xyz = position(model, target_from_source, *a)?;
    let b_xyz = position(model, target_from_source, *b)?;
    let distance_m = (0..3)
        .map(|k| (b_xyz[k] - a_xyz[k]).powi(2))
        .sum::<f64>()
        .sqrt();
    Some(Measurement {
        a: *a,
        b: *b,
        a_xyz,
        b_xyz,
        distance_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn model() -> InspectorModel {
        let mut m = InspectorModel::demo();
        m.source = vec![[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [1.0, 1.0, 1.0]];
        m.target = vec![[0.0, 0.0, 0.5], [10.0, 0.0, 0.0]];
        m
    }

    fn picks(p: &[(Cloud, usize)]) -> Measure {
        let mut m = Measure {
            active: true,
            picked: Vec::new(),
        };
        for &(cloud, index) in p {
            m.pick(Picked { cloud, index });
        }
        m
    }

    #[test]
    fn two_points_of_one_cloud_measure_the_same_under_any_pose() {
        let m = model();
        let pose = Isometry3::from_parts(
            Translation3::new(5.0, -2.0, 1.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.7),
        );
        let two = picks(&[(Cloud::Source, 0), (Cloud::Source, 1)]);
        for t in [Isometry3::identity(), pose] {
            let d = measurement(&m, &t, &two).unwrap();
            assert!((d.distance_m - 5.0).abs() < 1e-9, "{d:?}");
        }
        let t = measurement(&m, &pose, &picks(&[(Cloud::Target, 1), (Cloud::Target, 0)])).unwrap();
        assert!((t.distance_m - (100.0f64 + 0.25).sqrt()).abs() < 1e-9);
        assert_eq!(t.delta(), [-10.0, 0.0, 0.5]);
    }

    #[test]
    fn a_source_to_target_distance_is_the_residual_under_the_pose() {
        let m = model();
        let shift = Isometry3::translation(0.0, 0.0, 0.5);
        let st = picks(&[(Cloud::Source, 0), (Cloud::Target, 0)]);
        assert!(measurement(&m, &shift, &st).unwrap().distance_m < 1e-12);
        let d = measurement(&m, &Isometry3::identity(), &st).unwrap();
        assert!((d.distance_m - 0.5).abs() < 1e-12);
        let text = d.text("estimate");
        assert!(
            text.contains("0.500 m (50.0 cm) under the estimate"),
            "{text}"
        );
    }

    #[test]
    fn a_third_pick_starts_again_and_missing_points_measure_nothing() {
        let m = model();
        let mut t = picks(&[(Cloud::Source, 0), (Cloud::Source, 1), (Cloud::Target, 1)]);
        assert_eq!(t.picked.len(), 1);
        assert!(measurement(&m, &Isometry3::identity(), &t).is_none());
        t.pick(Picked {
            cloud: Cloud::Source,
            index: 99,
        });
        assert!(measurement(&m, &Isometry3::identity(), &t).is_none());
        t.clear();
        assert!(t.picked.is_empty());
        assert_eq!(format_distance(12.3456), "12.346 m");
    }
}
