//! Distances that follow the keypoint voxel unless the user sets them.
//!
//! The rule (one for every distance of the pipeline): a distance is a fixed multiple of the
//! keypoint voxel v, the multiple taken from SC2-PCR's published 3DMatch configuration
//! (`config_3DMatch.json`: downsample 0.05 m, `d_thre` = `inlier_threshold` = 0.10 m):
//!
//! | distance | multiple | 3DMatch (v = 0.05 m) | KITTI (v = 0.3 m) |
//! |---|---|---|---|
//! | SC2-PCR compatibility `d_thre` | 2 v | 0.10 m | 0.6 m |
//! | SC2-PCR inlier threshold | 2 v | 0.10 m | 0.6 m |
//! | GT inlier-ratio threshold | 2 v | 0.10 m | 0.6 m |
//! | lift radius (image branch) | 1 v | 0.05 m | 0.3 m |
//! | RANSAC inlier distance | 1.5 v | 0.075 m | 0.45 m |
//! | FPFH normal / feature radius | 2 v / 5 v | 0.10 / 0.25 m | 0.6 / 1.5 m |
//!
//! The same multiple reproduces SC2-PCR's published KITTI configuration (`config_KITTI.json`:
//! downsample 0.3 m with `d_thre` = `inlier_threshold` = 0.6 m). SC2-PCR's `nms_radius` is
//! 0.10 m in both configurations, so it does not follow the voxel.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// SC2-PCR `d_thre` and inlier threshold, and the GT inlier-ratio threshold, per voxel.
pub const THRESHOLD_PER_VOXEL: f64 = 2.0;
/// The image branch's lift radius per voxel.
pub const LIFT_RADIUS_PER_VOXEL: f64 = 1.0;
/// RANSAC's inlier distance per voxel (Open3D's global-registration example: 1.5 v).
pub const RANSAC_PER_VOXEL: f64 = 1.5;
/// The voxel an estimator called without one (outside the pipeline) resolves a following
/// distance at: SC2-PCR's 3DMatch configuration, its published default.
pub const REFERENCE_VOXEL: f64 = 0.05;

/// A length in metres stored as f32 or f64 (each field keeps the type it always had, so a
/// resolved value serialises exactly as before and cache keys stay valid).
pub trait Metres: Copy + PartialEq + std::fmt::Debug {
    fn from_m(m: f64) -> Self;
    fn to_m(self) -> f64;
}

impl Metres for f32 {
    fn from_m(m: f64) -> Self {
        m as f32
    }
    fn to_m(self) -> f64 {
        self as f64
    }
}

impl Metres for f64 {
    fn from_m(m: f64) -> Self {
        m
    }
    fn to_m(self) -> f64 {
        self
    }
}

/// A distance of the pipeline: follows the keypoint voxel by [`THRESHOLD_PER_VOXEL`] etc.,
/// or set by the user. Serialised as its number when set and as `"voxel"` when it follows;
/// files written before this type existed hold numbers and read as set values.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Scaled<T> {
    #[default]
    FollowVoxel,
    Set(T),
}

impl<T: Metres> Scaled<T> {
    /// The value at `voxel` with `per_voxel` the multiple of this distance.
    pub fn at(self, voxel: f64, per_voxel: f64) -> T {
        match self {
            Scaled::FollowVoxel => T::from_m(voxel * per_voxel),
            Scaled::Set(v) => v,
        }
    }

    /// Set to its value at `voxel` (a resolved copy: what the stages read and the keys hash).
    pub fn resolved(self, voxel: f64, per_voxel: f64) -> Scaled<T> {
        Scaled::Set(self.at(voxel, per_voxel))
    }

    pub fn follows_voxel(self) -> bool {
        matches!(self, Scaled::FollowVoxel)
    }
}

impl<T: Serialize> Serialize for Scaled<T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Scaled::FollowVoxel => s.serialize_str("voxel"),
            Scaled::Set(v) => v.serialize(s),
        }
    }
}

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Scaled<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Repr<T> {
            Set(T),
            Word(String),
        }
        match Repr::<T>::deserialize(d)? {
            Repr::Set(v) => Ok(Scaled::Set(v)),
            Repr::Word(w) if w == "voxel" => Ok(Scaled::FollowVoxel),
            Repr::Word(w) => Err(serde::de::Error::custom(format!(
                "expected a distance in metres or \"voxel\" (follows the keypoint voxel), got {w:?}"
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rule_reproduces_both_published_sc2pcr_configurations() {
        // 3DMatch: 0.05 m -> 0.10 m, bit for bit the constants the pipeline always used
        let t: Scaled<f32> = Scaled::FollowVoxel;
        assert_eq!(t.at(0.05, THRESHOLD_PER_VOXEL), 0.10f32);
        assert_eq!(
            Scaled::<f64>::FollowVoxel.at(0.05, THRESHOLD_PER_VOXEL),
            0.10f64
        );
        assert_eq!(t.at(0.05, LIFT_RADIUS_PER_VOXEL), 0.05f32);
        assert_eq!(t.at(0.05, RANSAC_PER_VOXEL), 0.075f32);
        // KITTI: 0.3 m -> 0.6 m
        assert_eq!(t.at(0.3, THRESHOLD_PER_VOXEL), 0.6f32);
        assert_eq!(Scaled::<f64>::FollowVoxel.at(0.3, THRESHOLD_PER_VOXEL), 0.6);
        // a set value ignores the voxel
        assert_eq!(Scaled::Set(0.25f32).at(0.3, THRESHOLD_PER_VOXEL), 0.25);
    }

    #[test]
    fn serialises_as_a_number_or_voxel_and_reads_old_numbers() {
        let set: Scaled<f32> = serde_json::from_str("0.1").unwrap();
        assert_eq!(set, Scaled::Set(0.1));
        assert_eq!(serde_json::to_string(&set).unwrap(), "0.1");
        let f: Scaled<f64> = serde_json::from_str("\"voxel\"").unwrap();
        assert_eq!(f, Scaled::FollowVoxel);
        assert_eq!(serde_json::to_string(&f).unwrap(), "\"voxel\"");
        let e = serde_json::from_str::<Scaled<f64>>("\"auto\"").unwrap_err();
        assert!(e.to_string().contains("\"voxel\""), "{e}");
    }
}
