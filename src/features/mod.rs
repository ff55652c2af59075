//! Geometric-branch features: FPFH (hand-crafted) and precomputed learned features
//! (GeoTransformer, FCGF, Predator) loaded from files.

pub mod fpfh;
pub mod learned;
pub mod spinnet;

/// A geometric descriptor a data set's manifest or a run names by its name: `fpfh`,
/// `spinnet-3dmatch` or `spinnet-kitti` (the names of `--geo-features`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DescriptorName {
    Fpfh,
    Spinnet(spinnet::Protocol),
}

impl DescriptorName {
    pub const ALL: [DescriptorName; 3] = [
        DescriptorName::Fpfh,
        DescriptorName::Spinnet(spinnet::Protocol::ThreeDMatch),
        DescriptorName::Spinnet(spinnet::Protocol::Kitti),
    ];

    pub fn name(self) -> &'static str {
        match self {
            DescriptorName::Fpfh => "fpfh",
            DescriptorName::Spinnet(spinnet::Protocol::ThreeDMatch) => "spinnet-3dmatch",
            DescriptorName::Spinnet(spinnet::Protocol::Kitti) => "spinnet-kitti",
        }
    }

    /// The descriptor of `name`, None for another text.
    pub fn parse(name: &str) -> Option<DescriptorName> {
        Self::ALL.into_iter().find(|d| d.name() == name)
    }
}

/// Dense per-point features, row-major: row i is the feature of point i.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Features {
    pub dim: usize,
    pub data: Vec<f32>,
}

impl Features {
    pub fn new(dim: usize, data: Vec<f32>) -> Self {
        debug_assert!(dim == 0 || data.len().is_multiple_of(dim));
        Features { dim, data }
    }
    pub fn len(&self) -> usize {
        self.data.len().checked_div(self.dim).unwrap_or(0)
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.dim..(i + 1) * self.dim]
    }
    /// A copy with every row scaled to unit L2 norm (rows of norm < eps stay zero).
    pub fn l2_normalized(&self) -> Features {
        let mut data = self.data.clone();
        if self.dim > 0 {
            for row in data.chunks_mut(self.dim) {
                let n = row.iter().map(|v| v * v).sum::<f32>().sqrt();
                if n > 1e-12 {
                    row.iter_mut().for_each(|v| *v /= n);
                }
            }
        }
        Features {
            dim: self.dim,
            data,
        }
    }
}
