use nalgebra::{Isometry3, Point3, Vector3};

/// A point cloud in metres. Optional attributes, when present, have one entry per point.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    pub points: Vec<Point3<f32>>,
    pub colors: Option<Vec<[u8; 3]>>,
    pub normals: Option<Vec<Vector3<f32>>>,
    pub intensity: Option<Vec<f32>>,
}

impl PointCloud {
    pub fn from_points(points: Vec<Point3<f32>>) -> Self {
        PointCloud {
            points,
            ..Default::default()
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// A copy with every point (and normal) mapped by `t` (p' = t * p).
    pub fn transformed(&self, t: &Isometry3<f64>) -> PointCloud {
        let tf: Isometry3<f32> = t.cast();
        PointCloud {
            points: self.points.iter().map(|p| tf * p).collect(),
            normals: self
                .normals
                .as_ref()
                .map(|ns| ns.iter().map(|n| tf.rotation * n).collect()),
            colors: self.colors.clone(),
            intensity: self.intensity.clone(),
        }
    }

    /// Axis-aligned bounds (min, max); None for an empty cloud.
    pub fn bounds(&self) -> Option<(Point3<f32>, Point3<f32>)> {
        let first = *self.points.first()?;
        Some(
            self.points
                .iter()
                .fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p))),
        )
    }

    pub fn centroid(&self) -> Option<Point3<f32>> {
        if self.points.is_empty() {
            return None;
        }
        let s = self.points.iter().fold(Vector3::<f64>::zeros(), |acc, p| {
            acc + p.coords.cast::<f64>()
        });
        Some(Point3::from((s / self.points.len() as f64).cast::<f32>()))
    }

    /// Keep the points at `indices`, with their attributes.
    pub fn select(&self, indices: &[usize]) -> PointCloud {
        PointCloud {
            points: indices.iter().map(|&i| self.points[i]).collect(),
            colors: self
                .colors
                .as_ref()
                .map(|c| indices.iter().map(|&i| c[i]).collect()),
            normals: self
                .normals
                .as_ref()
                .map(|c| indices.iter().map(|&i| c[i]).collect()),
            intensity: self
                .intensity
                .as_ref()
                .map(|c| indices.iter().map(|&i| c[i]).collect()),
        }
    }
}
