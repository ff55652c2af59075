//! One keypoint's network input from its patch: centre on the keypoint (the patch's last
//! point), the local reference frame (3DMatch), the per-voxel ball query and `var_to_invar`.

use super::{ball_query, grid, invariant, lrf, Geometry};

/// The patch centred on its last point and, when the protocol has one, rotated into the local
/// reference frame (the authors' `delta_x` before the ball query).
pub fn local_points(g: &Geometry, patch: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let Some(&kp) = patch.last() else {
        return Vec::new();
    };
    let mut local: Vec<[f32; 3]> = patch
        .iter()
        .map(|p| [p[0] - kp[0], p[1] - kp[1], p[2] - kp[2]])
        .collect();
    if g.lrf {
        // a patch with no frame (non-finite points) stays as it is
        lrf::rotate_into_frame(&mut local, kp);
    }
    local
}

/// The network's input for one patch: (voxels, voxel_sample, 3) flattened. `centres` are
/// [`grid::voxel_centres`] of `g` (computed once per cloud).
pub fn grouped(g: &Geometry, patch: &[[f32; 3]], centres: &[[f32; 3]]) -> Vec<f32> {
    let local = local_points(g, patch);
    let mut out = ball_query::group(g, &local, centres);
    invariant::var_to_invar(g, &mut out);
    out
}

/// [`grouped`] with the centres computed here (tests, one-off calls).
pub fn grouped_once(g: &Geometry, patch: &[[f32; 3]]) -> Vec<f32> {
    grouped(g, patch, &grid::voxel_centres(g))
}
