//! Point clouds, voxel grids, normals, neighbour search (kiddo) and rigid transforms.

pub mod cloud;
pub mod knn;
pub mod normals;
pub mod transform;
pub mod voxel;

pub use cloud::PointCloud;

/// `x.floor() as i64`, the same value for every `f64` (NaN and the infinities included), without
/// the call into the software `floor` that the baseline x86-64 target makes (its rounding
/// instruction needs SSE4.1): voxel keys take three per point.
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    // `as` truncates toward zero and saturates; one step down where that rounded up.
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

#[cfg(test)]
mod tests {
    use super::floor_i64;

    #[test]
    fn floor_i64_equals_floor_as_i64_everywhere() {
        let mut s = crate::testing::Lcg(7);
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5,
            -2.5,
            -3.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            9.223_372_036_854_775e18,
            -9.223_372_036_854_775e18,
            9.3e18,
            -9.3e18,
            4_503_599_627_370_496.5,
            -4_503_599_627_370_495.5,
        ];
        for _ in 0..100_000 {
            // Random bit patterns cover every exponent; scaled uniforms cover voxel-sized values.
            xs.push(f64::from_bits(s.next_u64()));
            xs.push((s.unit_f64() - 0.5) * 2e4);
        }
        for x in xs {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x:e}");
        }
    }
}
