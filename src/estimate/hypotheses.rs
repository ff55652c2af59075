//! The ranked hypotheses of an estimator (the inspector's hypothesis browser): SC2-PCR's
//! seeds ranked by consensus size, RANSAC's best samples ranked by its own order. An optional
//! output ([`super::estimate_pose_with_hypotheses`]); the default path
//! ([`super::estimate_pose`]) collects none.
//!
//! Memory is bounded: the best `top_n` are kept ([`TopN`], at most `top_n` entries at any
//! time besides one chunk of RANSAC's), and only those get their inlier lists.

use nalgebra::Isometry3;

/// Hypotheses kept when the caller does not say (the inspector's list).
pub const DEFAULT_TOP_N: usize = 20;

/// One hypothesis of an estimator.
#[derive(Clone, Debug, PartialEq)]
pub struct Hypothesis {
    /// 1 = the best by the estimator's own rule ([`Hypotheses::rule`]).
    pub rank: usize,
    /// The correspondences it was built from: SC2-PCR, the seed; RANSAC, the 3-point sample.
    pub sample: Vec<usize>,
    /// Its consensus: correspondences within the estimator's threshold under `pose`.
    pub consensus: usize,
    /// RANSAC's tie-breaker: sum of squared inlier residuals (m²); None for SC2-PCR.
    pub sse: Option<f64>,
    /// Its pose, `target_from_source`, before any refinement.
    pub pose: Isometry3<f64>,
    /// Indices (into the correspondences given to the estimator) of its consensus.
    pub inliers: Vec<usize>,
    /// The hypothesis the estimator chose; its refinement is [`Hypotheses::refined`].
    pub winner: bool,
}

/// The best hypotheses of one estimator run, best first.
#[derive(Clone, Debug, PartialEq)]
pub struct Hypotheses {
    /// "sc2pcr" or "ransac".
    pub estimator: String,
    /// How they are ranked (the estimator's own selection rule).
    pub rule: String,
    /// The consensus threshold (m).
    pub threshold_m: f64,
    /// Hypotheses the estimator scored in all; `list` holds the best of them.
    pub total: usize,
    pub list: Vec<Hypothesis>,
    /// The pose the estimator returned: the winner after its refinement.
    pub refined: Isometry3<f64>,
}

impl Hypotheses {
    pub fn winner(&self) -> Option<&Hypothesis> {
        self.list.iter().find(|h| h.winner)
    }

    /// As [`super::Estimate::reindexed`]: samples and inliers back to input indices.
    pub(crate) fn reindexed(mut self, order: &[usize]) -> Self {
        for h in &mut self.list {
            h.sample = h.sample.iter().map(|&k| order[k]).collect();
            h.inliers = reindex(&h.inliers, order);
        }
        self
    }
}

/// `order[k]` for each k of `positions`, ascending.
pub(crate) fn reindex(positions: &[usize], order: &[usize]) -> Vec<usize> {
    let mut v: Vec<usize> = positions.iter().map(|&k| order[k]).collect();
    v.sort_unstable();
    v
}

/// The best `n` items under a strict order `better(a, b)` (a before b), best first.
/// Insertion is O(n); n is small (tens).
pub(crate) struct TopN<T> {
    n: usize,
    items: Vec<T>,
}

impl<T> TopN<T> {
    pub(crate) fn new(n: usize) -> Self {
        TopN {
            n,
            items: Vec::with_capacity(n.min(1024)),
        }
    }

    pub(crate) fn push(&mut self, x: T, better: impl Fn(&T, &T) -> bool) {
        if self.n == 0 {
            return;
        }
        if self.items.len() == self.n && self.items.last().is_some_and(|l| !better(&x, l)) {
            return;
        }
        let at = self.items.partition_point(|y| better(y, &x));
        self.items.insert(at, x);
        self.items.truncate(self.n);
    }

    pub(crate) fn into_vec(self) -> Vec<T> {
        self.items
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn top_n_keeps_the_best_in_order() {
        let mut t = TopN::new(3);
        for x in [5, 1, 9, 3, 9, 7, 2] {
            t.push(x, |a: &i32, b: &i32| a > b);
        }
        assert_eq!(t.into_vec(), vec![9, 9, 7]);
        let mut z = TopN::new(0);
        z.push(1, |a: &i32, b: &i32| a > b);
        assert!(z.into_vec().is_empty());
    }
}
