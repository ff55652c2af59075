//! Point clouds, voxel grids, normals, neighbour search (kiddo) and rigid transforms.

pub mod cloud;
pub mod knn;
pub mod normals;
pub mod transform;
pub mod voxel;

pub use cloud::PointCloud;
