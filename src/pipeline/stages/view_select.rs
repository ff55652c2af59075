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
pub const STAGE: &str = "view-selection";
pub const VERSION: u32 = 1;

/// The selection's key: L, m and K, and the generated video's length.
pub fn key(ib: &ImageBranchParams, n_generated: usize) -> Result<CacheKey> {
    CacheKey::new(
        STAGE,
        VERSION,
        &[],
        &json!({ "L": ib.frames_per_fragment, "m": ib.margin, "K": ib.k, "n_generated": n_generated }),
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
/// frames), timed as "view selection".
pub(crate) fn run(
    ctx: &mut Ctx,
    planned: ViewSelection,
    n_generated: usize,
    ib: &ImageBranchParams,
) -> Result<ViewSelection> {
    let t = Instant::now();
    let sel = select(planned, n_generated, ib)?;
    ctx.timer.record("view selection", t.elapsed(), false);
    Ok(sel)
}
