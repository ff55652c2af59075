//! The `union` fusion rule: the paper's Noisy-AND correspondences and the geometric branch's
//! own correspondences (row nearest neighbours, the geometry-alone registration's set) go to
//! the estimator together, Noisy-AND's first, each (source, target) pair once. A weak image
//! branch can veto FPFH's correct matches out of a Noisy-AND set; here it cannot remove them,
//! and SC2-PCR's spatial compatibility picks the consistent ones from both.
//!
//! Chosen on development pairs by the written protocol (docs/ablation.md, "A fusion that never
//! loses to its best branch"), among pose consensus over the branches' poses, this union, and
//! a Noisy-AND with unseen points neutral.

use super::Correspondence;
use serde::{Deserialize, Serialize};

/// Where a correspondence of the union came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Origin {
    NoisyAnd,
    Geometry,
    /// In both sets.
    Both,
}

/// `first` then the pairs of `then` not in `first`, each (source, target) pair once (a pair
/// repeated inside one set is kept once, at its first place), with each one's origin. A pair
/// keeps its score in `first` (Noisy-AND's posterior); the scores are read only by a weighted
/// SVD (SC2-PCR's fallback).
pub fn merge(
    first: &[Correspondence],
    then: &[Correspondence],
) -> (Vec<Correspondence>, Vec<Origin>) {
    let mut at = std::collections::HashMap::with_capacity(first.len() + then.len());
    let mut out = Vec::with_capacity(first.len() + then.len());
    let mut origin = Vec::with_capacity(first.len() + then.len());
    for (set, o) in [(first, Origin::NoisyAnd), (then, Origin::Geometry)] {
        for c in set {
            match at.get(&(c.src, c.tgt)) {
                None => {
                    at.insert((c.src, c.tgt), out.len());
                    out.push(*c);
                    origin.push(o);
                }
                Some(&i) if origin[i] != o => origin[i] = Origin::Both,
                Some(_) => {}
            }
        }
    }
    (out, origin)
}

/// What the `union` fusion gave the estimator and where its inliers came from: the result's
/// provenance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnionReport {
    pub n_noisy_and: usize,
    pub n_geometry: usize,
    /// Distinct pairs of the union (what the estimator was given).
    pub n_union: usize,
    /// The estimator's inliers by origin.
    pub inliers_noisy_and: usize,
    pub inliers_geometry: usize,
    pub inliers_both: usize,
}

impl UnionReport {
    /// From the two sets' sizes, the union's origins and the estimator's inliers (indices
    /// into the union; out-of-range indices are ignored).
    pub fn new(
        n_noisy_and: usize,
        n_geometry: usize,
        origin: &[Origin],
        inliers: &[usize],
    ) -> Self {
        let count = |o: Origin| {
            inliers
                .iter()
                .filter(|&&i| origin.get(i) == Some(&o))
                .count()
        };
        UnionReport {
            n_noisy_and,
            n_geometry,
            n_union: origin.len(),
            inliers_noisy_and: count(Origin::NoisyAnd),
            inliers_geometry: count(Origin::Geometry),
            inliers_both: count(Origin::Both),
        }
    }

    /// One line, e.g. "fusion: union (1030 Noisy-AND + 6256 geometry correspondences, 7279
    /// distinct; inliers 139: 102 geometry only, 37 Noisy-AND only, 0 both)".
    pub fn provenance(&self) -> String {
        let n = self.inliers_noisy_and + self.inliers_geometry + self.inliers_both;
        format!(
            "fusion: union ({} Noisy-AND + {} geometry correspondences, {} distinct; inliers {n}: \
             {} geometry only, {} Noisy-AND only, {} both)",
            self.n_noisy_and,
            self.n_geometry,
            self.n_union,
            self.inliers_geometry,
            self.inliers_noisy_and,
            self.inliers_both
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(src: u32, tgt: u32, score: f32) -> Correspondence {
        Correspondence { src, tgt, score }
    }

    #[test]
    fn merge_keeps_the_first_set_first_and_each_pair_once() {
        let and = [c(0, 1, 0.9), c(2, 3, 0.8), c(0, 1, 0.1)];
        let geo = [c(2, 3, 0.5), c(4, 5, 0.4), c(0, 2, 0.3), c(4, 5, 0.2)];
        let (u, o) = merge(&and, &geo);
        let pairs: Vec<(u32, u32)> = u.iter().map(|x| (x.src, x.tgt)).collect();
        assert_eq!(pairs, vec![(0, 1), (2, 3), (4, 5), (0, 2)]);
        // Noisy-AND's score is kept for a pair in both sets
        assert_eq!(u[1].score, 0.8);
        assert_eq!(
            o,
            vec![
                Origin::NoisyAnd,
                Origin::Both,
                Origin::Geometry,
                Origin::Geometry
            ]
        );
        // an empty first set is the geometric set (duplicates dropped), in its order
        let (g, og) = merge(&[], &geo);
        assert_eq!(g.len(), 3);
        assert!(og.iter().all(|&x| x == Origin::Geometry));
        assert_eq!((g[0].src, g[2].tgt), (2, 2));
    }

    #[test]
    fn report_counts_inliers_by_origin_and_names_them() {
        let and = [c(0, 1, 0.9), c(2, 3, 0.8)];
        let geo = [c(2, 3, 0.5), c(4, 5, 0.4), c(6, 7, 0.3)];
        let (_, o) = merge(&and, &geo);
        // inliers: (0,1) Noisy-AND only, (2,3) both, (6,7) geometry only; 99 out of range
        let r = UnionReport::new(and.len(), geo.len(), &o, &[0, 1, 3, 99]);
        assert_eq!(r.n_union, 4);
        assert_eq!(
            (r.inliers_noisy_and, r.inliers_geometry, r.inliers_both),
            (1, 1, 1)
        );
        assert_eq!(
            r.provenance(),
            "fusion: union (2 Noisy-AND + 3 geometry correspondences, 4 distinct; inliers 3: \
             1 geometry only, 1 Noisy-AND only, 1 both)"
        );
    }
}
