//! View selection (reference §2: K views per side by the stride rule, m frames of safeguard
//! margin): in memory, trivial, so not cached. Parameters: L, m, K and the generated video's
//! length.

use super::Ctx;
use crate::cache::CacheKey;
use crate::error::Result;
use crate::pipeline::params::ImageBranchParams;
use crate::wfm::ViewSelection;
use serde_json::json;
use std::time::Instant;

/// The stage's name in key comparisons (it is not cached: no folder of that name).
pub const STAGE: &str = NAME.key_name();
pub const VERSION: u32 = 1;
pub const NAME: crate::pipeline::graph::StageName = crate::pipeline::graph::StageName::ViewSelect;

/// The selection's key: L, m and K, and the generated video's length.
pub fn key(ib: &ImageBranchParams, n_generated: usize) -> Result<CacheKey> {
    let ImageBranchParams {
        backend: _,
        prompt: _,
        seed: _,
        vfm: _,
        k,
        margin,
        frames_per_fragment,
        lift_radius: _,
        virtual_camera: _,
        lidar_cameras: _,
        lidar_origin: _,
        dense_stride: _,
    } = ib;
    CacheKey::new(
        STAGE,
        VERSION,
        &[],
        &json!({ "L": frames_per_fragment, "m": margin, "K": k, "n_generated": n_generated }),
    )
}

/// The selection on a video of `n_generated` frames (`planned` when that is 2L).
pub(crate) fn select(
    planned: ViewSelection,
    n_generated: usize,
    ib: &ImageBranchParams,
) -> Result<ViewSelection> {
    let l = ib.frames_per_fragment;
    if n_generated == 2 * l {
        Ok(planned)
    } else {
        crate::wfm::select_views(n_generated, l, ib.margin, ib.k)
    }
}

/// The selection for a video of exactly 2L frames: run before anything expensive, so a bad
/// K or m fails early.
pub(crate) fn planned(ib: &ImageBranchParams) -> Result<ViewSelection> {
    let l = ib.frames_per_fragment;
    crate::wfm::select_views(2 * l, l, ib.margin, ib.k)
}

/// The selection on the generated video's actual length (a backend may return more than 2L
/// frames), timed as "view selection"; with its key.
pub(crate) fn run(
    ctx: &mut Ctx,
    planned: ViewSelection,
    n_generated: usize,
    ib: &ImageBranchParams,
) -> Result<(ViewSelection, CacheKey)> {
    let t = Instant::now();
    let sel = select(planned, n_generated, ib)?;
    ctx.timer
        .record_as(NAME, "view selection", t.elapsed(), false);
    Ok((sel, key(ib, n_generated)?))
}
