//! The frame split of the generated video and the choice of the K views (reference §3).
//!
//! The generated video is `L` source frames then `L` target frames. With safeguard margin `m`,
//! source = generated `[0, L - m)` and target = generated `[L + m, 2L)`; the `2m` frames around
//! the seam are dropped. Views: `sel = (0..L - m).step_by((L - m) / K).take(K)`; the source
//! views are generated frames `sel` (depth frames `sel` of the source fragment), the target
//! views are generated frames `L + m + sel` (depth frames `m + sel` of the target fragment).
//! K = 4, L = 50, m = 3 gives [0, 11, 22, 33], [53, 64, 75, 86] and [3, 14, 25, 36].

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ViewSelection {
    /// Indices into the generated video of the source views.
    pub src_generated: Vec<usize>,
    /// Indices into the source fragment's depth frames, one per source view.
    pub src_depth: Vec<usize>,
    /// Indices into the generated video of the target views.
    pub tgt_generated: Vec<usize>,
    /// Indices into the target fragment's depth frames, one per target view.
    pub tgt_depth: Vec<usize>,
}

/// Select K views per side. `n_generated` is the number of frames of the generated video,
/// `l` the frames per fragment, `margin` the safeguard margin, `k` the views per side.
pub fn select_views(
    n_generated: usize,
    l: usize,
    margin: usize,
    k: usize,
) -> Result<ViewSelection> {
    if l == 0 {
        return Err(Error::Param(
            "frames per fragment L must be at least 1".into(),
        ));
    }
    if margin >= l {
        return Err(Error::Param(format!(
            "safeguard margin m = {margin} leaves no frames: it must be smaller than L = {l}"
        )));
    }
    if n_generated < 2 * l {
        return Err(Error::Shape(format!(
            "the generated video has {n_generated} frames; {} are needed (L = {l} source then \
             L target frames)",
            2 * l
        )));
    }
    let usable = l - margin;
    if k == 0 || k > usable {
        return Err(Error::Param(format!(
            "K = {k} views is invalid: K must be between 1 and L - m = {l} - {margin} = {usable}"
        )));
    }
    let step = usable / k;
    let sel: Vec<usize> = (0..usable).step_by(step).take(k).collect();
    Ok(ViewSelection {
        src_generated: sel.clone(),
        src_depth: sel.clone(),
        tgt_generated: sel.iter().map(|s| l + margin + s).collect(),
        tgt_depth: sel.iter().map(|s| margin + s).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_k4() {
        let v = select_views(100, 50, 3, 4).unwrap();
        assert_eq!(v.src_generated, vec![0, 11, 22, 33]);
        assert_eq!(v.src_depth, vec![0, 11, 22, 33]);
        assert_eq!(v.tgt_generated, vec![53, 64, 75, 86]);
        assert_eq!(v.tgt_depth, vec![3, 14, 25, 36]);
    }

    #[test]
    fn reference_k_values() {
        let sel = |k| select_views(100, 50, 3, k).unwrap().src_generated;
        assert_eq!(sel(1), vec![0]);
        assert_eq!(sel(2), vec![0, 23]);
        assert_eq!(sel(8), (0..8).map(|i| 5 * i).collect::<Vec<_>>());
        assert_eq!(sel(16), (0..16).map(|i| 2 * i).collect::<Vec<_>>());
        assert_eq!(sel(32), (0..32).collect::<Vec<_>>());
        assert_eq!(sel(47), (0..47).collect::<Vec<_>>());
        // Brute force: K distinct, increasing, inside [0, 47), target stays inside [53, 100).
        for k in 1..=47 {
            let v = select_views(100, 50, 3, k).unwrap();
            assert_eq!(v.src_generated.len(), k);
            assert!(v.src_generated.windows(2).all(|w| w[0] < w[1]));
            assert!(v.src_generated.iter().all(|&s| s < 47));
            assert!(v.tgt_generated.iter().all(|&t| (53..100).contains(&t)));
            assert!(v.tgt_depth.iter().all(|&t| t < 50));
        }
    }

    #[test]
    fn invalid_inputs_are_clear_errors() {
        let e = select_views(100, 50, 3, 0).unwrap_err().to_string();
        assert!(e.contains("K = 0") && e.contains("47"), "{e}");
        let e = select_views(100, 50, 3, 48).unwrap_err().to_string();
        assert!(e.contains("K = 48"), "{e}");
        assert!(select_views(99, 50, 3, 4).is_err());
        assert!(select_views(100, 50, 50, 1).is_err());
        assert!(select_views(100, 0, 0, 1).is_err());
        // Margin 0 and other L work.
        let v = select_views(20, 10, 0, 2).unwrap();
        assert_eq!(v.src_generated, vec![0, 5]);
        assert_eq!(v.tgt_generated, vec![10, 15]);
    }
}
