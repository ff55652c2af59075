//! The `consensus` fusion rule: estimate a pose from each candidate correspondence set (the
//! geometry-alone set, the paper's Noisy-AND set and the image-alone set), score every pose on
//! the union of the sets (branch-neutral: no branch's posterior enters the score) and keep the
//! pose with the most pairs within the inlier threshold. Ties go to the lower truncated-residual
//! (MSAC) score over the same union, then to the fixed order of [`Candidate::ORDER`].
//!
//! Chosen on development pairs only (docs/ablation.md, "A fusion that never loses to its best
//! branch"). A weak image branch can only add a candidate; it cannot remove the geometric one.

use super::Correspondence;
use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

/// One candidate correspondence set of the consensus rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Candidate {
    /// The geometric branch alone, row nearest neighbours (the geometry-alone registration).
    Geometry,
    /// The paper's Noisy-AND fusion with the run's selection.
    NoisyAnd,
    /// The image branch alone with the run's selection.
    Image,
}

impl Candidate {
    /// Every candidate, in the tie-break order (the branch that needs no views first).
    pub const ORDER: [Candidate; 3] = [Candidate::Geometry, Candidate::NoisyAnd, Candidate::Image];

    pub fn label(self) -> &'static str {
        match self {
            Candidate::Geometry => "geometry",
            Candidate::NoisyAnd => "noisy-and",
            Candidate::Image => "image",
        }
    }

    fn rank(self) -> usize {
        Candidate::ORDER
            .iter()
            .position(|&c| c == self)
            .unwrap_or(usize::MAX)
    }
}

/// The candidates the `consensus` mode estimates and chooses from, in the tie-break order.
pub const CANDIDATES: &[Candidate] = &Candidate::ORDER;

/// A pose's fit to the branch-neutral set.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fit {
    /// Pairs of the union with ‖T s − t‖ ≤ θ.
    pub consensus: usize,
    /// Σ min(r², θ²) / θ² over the union: lower is better (MSAC's truncated squared residual).
    pub msac: f64,
}

/// [`Fit`] of `target_from_source` on the correspondences `src[i] ↔ tgt[i]` at threshold `theta`.
pub fn fit(
    target_from_source: &Isometry3<f64>,
    src: &[Point3<f32>],
    tgt: &[Point3<f32>],
    theta: f64,
) -> Fit {
    let t2 = theta * theta;
    let mut consensus = 0usize;
    let mut msac = 0.0f64;
    for (s, t) in src.iter().zip(tgt) {
        let p = target_from_source * s.cast::<f64>();
        let r2 = (p - t.cast::<f64>()).norm_squared();
        // NaN residuals count as outliers
        if r2 <= t2 {
            consensus += 1;
            msac += r2 / t2;
        } else {
            msac += 1.0;
        }
    }
    Fit { consensus, msac }
}

/// The distinct (source, target) keypoint pairs of the given sets, in first-seen order.
pub fn union(sets: &[&[Correspondence]]) -> Vec<(u32, u32)> {
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for set in sets {
        for c in set.iter() {
            if seen.insert((c.src, c.tgt)) {
                out.push((c.src, c.tgt));
            }
        }
    }
    out
}

/// What decided the choice.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Decided {
    /// One candidate had the largest consensus.
    Consensus,
    /// Largest consensus tied; the lower MSAC score decided.
    Msac,
    /// Consensus and MSAC tied; the fixed order decided.
    Order,
    /// Only one candidate could be estimated.
    Only,
}

/// The index of the winning candidate among `scored` and what decided it; None when empty.
pub fn decide(scored: &[(Candidate, Fit)]) -> Option<(usize, Decided)> {
    let best_c = scored.iter().map(|(_, f)| f.consensus).max()?;
    let top: Vec<usize> = (0..scored.len())
        .filter(|&i| scored[i].1.consensus == best_c)
        .collect();
    if scored.len() == 1 {
        return Some((0, Decided::Only));
    }
    if top.len() == 1 {
        return Some((top[0], Decided::Consensus));
    }
    let best_m = top
        .iter()
        .map(|&i| scored[i].1.msac)
        .fold(f64::INFINITY, f64::min);
    let low: Vec<usize> = top
        .iter()
        .copied()
        .filter(|&i| scored[i].1.msac == best_m)
        .collect();
    if low.len() == 1 {
        return Some((low[0], Decided::Msac));
    }
    // MSAC NaN-free by construction; all tied (or none finite): the fixed order
    let pool = if low.is_empty() { top } else { low };
    let i = pool.into_iter().min_by_key(|&i| scored[i].0.rank())?;
    Some((i, Decided::Order))
}

/// One candidate of a consensus decision, as results and tables report it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CandidateReport {
    pub candidate: Candidate,
    pub n_correspondences: usize,
    /// The estimator's own inliers on the candidate's set.
    pub estimator_inliers: usize,
    pub estimator: String,
    pub fit: Fit,
    /// Its estimate, p_target = T * p_source, row-major 4x4.
    pub target_from_source: [[f64; 4]; 4],
    /// Against ground truth, when the pair has one.
    pub rre_deg: Option<f64>,
    pub rte_m: Option<f64>,
    pub success: Option<bool>,
}

/// The decision of the consensus rule: which pose won and why (the result's provenance).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConsensusDecision {
    pub chosen: Candidate,
    pub decided_by: Decided,
    /// θ (m) of the consensus count: the pipeline's inlier threshold.
    pub threshold_m: f64,
    /// Size of the branch-neutral union the poses were scored on.
    pub union_size: usize,
    pub candidates: Vec<CandidateReport>,
    /// Why a candidate is missing (e.g. its estimator failed on a degenerate set).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub skipped: Vec<String>,
}

impl ConsensusDecision {
    fn report(&self, c: Candidate) -> Option<&CandidateReport> {
        self.candidates.iter().find(|r| r.candidate == c)
    }

    /// One line, e.g. "fusion: consensus (chose geometry, 312 vs noisy-and 198 / image 40
    /// inliers of 9876 at 0.10 m)".
    pub fn provenance(&self) -> String {
        let Some(win) = self.report(self.chosen) else {
            return "fusion: consensus (no candidate)".into();
        };
        let others: Vec<String> = self
            .candidates
            .iter()
            .filter(|r| r.candidate != self.chosen)
            .map(|r| format!("{} {}", r.candidate.label(), r.fit.consensus))
            .collect();
        let why = match self.decided_by {
            Decided::Consensus => String::new(),
            Decided::Msac => format!(
                "; tie, MSAC {:.1} vs {}",
                win.fit.msac,
                self.candidates
                    .iter()
                    .filter(|r| r.candidate != self.chosen && r.fit.consensus == win.fit.consensus)
                    .map(|r| format!("{:.1}", r.fit.msac))
                    .collect::<Vec<_>>()
                    .join(" / ")
            ),
            Decided::Order => "; tie in consensus and MSAC, fixed order".into(),
            Decided::Only => "; the only candidate estimated".into(),
        };
        format!(
            "fusion: consensus (chose {}, {} vs {} inliers of {} at {:.2} m{})",
            self.chosen.label(),
            win.fit.consensus,
            if others.is_empty() {
                "none".into()
            } else {
                others.join(" / ")
            },
            self.union_size,
            self.threshold_m,
            why
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn f(consensus: usize, msac: f64) -> Fit {
        Fit { consensus, msac }
    }

    #[test]
    fn largest_consensus_wins_whatever_the_order() {
        let s = [
            (Candidate::Geometry, f(198, 9000.0)),
            (Candidate::NoisyAnd, f(312, 9500.0)),
        ];
        assert_eq!(decide(&s), Some((1, Decided::Consensus)));
        let s = [s[1], s[0]];
        assert_eq!(decide(&s), Some((0, Decided::Consensus)));
    }

    #[test]
    fn a_tie_goes_to_the_lower_msac_then_to_the_fixed_order() {
        // 74 against 74: the continuous score decides, in either order
        let s = [
            (Candidate::Geometry, f(74, 900.0)),
            (Candidate::NoisyAnd, f(74, 880.5)),
            (Candidate::Image, f(10, 1.0)),
        ];
        assert_eq!(decide(&s), Some((1, Decided::Msac)));
        let r = [s[2], s[1], s[0]];
        assert_eq!(decide(&r), Some((1, Decided::Msac)));
        // both tie: geometry first, in whatever order they come
        let t = [
            (Candidate::Image, f(74, 900.0)),
            (Candidate::NoisyAnd, f(74, 900.0)),
            (Candidate::Geometry, f(74, 900.0)),
        ];
        assert_eq!(decide(&t), Some((2, Decided::Order)));
        let t = [t[0], t[1]];
        assert_eq!(decide(&t), Some((1, Decided::Order)));
        assert_eq!(decide(&[]), None);
        assert_eq!(
            decide(&[(Candidate::Image, f(0, 5.0))]),
            Some((0, Decided::Only))
        );
    }

    #[test]
    fn fit_counts_pairs_within_the_threshold_and_truncates_the_rest() {
        let t = Isometry3::from_parts(
            Translation3::new(1.0, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        );
        let src: Vec<Point3<f32>> = (0..10)
            .map(|i| Point3::new(i as f32 * 0.3, 0.1 * i as f32, 0.0))
            .collect();
        let mut tgt: Vec<Point3<f32>> = src
            .iter()
            .map(|p| (t * p.cast::<f64>()).cast::<f32>())
            .collect();
        // 3 outliers, one at exactly 0.05 m off (inside 0.1 m, residual (0.5)^2 of theta^2)
        tgt[0].x += 5.0;
        tgt[1].y -= 0.2;
        tgt[2].z += f32::NAN;
        tgt[3].z += 0.05;
        let fit = fit(&t, &src, &tgt, 0.1);
        assert_eq!(fit.consensus, 7);
        assert!((fit.msac - (3.0 + 0.25)).abs() < 1e-4, "{}", fit.msac);
        // a threshold from the params, not 0.1: at 0.3 m the 0.2 m outlier is in
        assert_eq!(super::fit(&t, &src, &tgt, 0.3).consensus, 8);
    }

    #[test]
    fn union_keeps_distinct_pairs_in_first_seen_order() {
        let c = |s, t| Correspondence {
            src: s,
            tgt: t,
            score: 0.5,
        };
        let a = [c(0, 1), c(2, 3)];
        let b = [c(2, 3), c(4, 5), c(0, 2)];
        assert_eq!(union(&[&a, &b]), vec![(0, 1), (2, 3), (4, 5), (0, 2)]);
    }

    #[test]
    fn provenance_names_the_winner_the_counts_and_the_reason() {
        let rep = |c, n, m| CandidateReport {
            candidate: c,
            n_correspondences: 100,
            estimator_inliers: 50,
            estimator: "sc2pcr".into(),
            fit: f(n, m),
            target_from_source: [[0.0; 4]; 4],
            rre_deg: None,
            rte_m: None,
            success: None,
        };
        let d = ConsensusDecision {
            chosen: Candidate::Geometry,
            decided_by: Decided::Consensus,
            threshold_m: 0.1,
            union_size: 9876,
            candidates: vec![
                rep(Candidate::Geometry, 312, 1.0),
                rep(Candidate::NoisyAnd, 198, 2.0),
            ],
            skipped: vec![],
        };
        assert_eq!(
            d.provenance(),
            "fusion: consensus (chose geometry, 312 vs noisy-and 198 inliers of 9876 at 0.10 m)"
        );
        let d = ConsensusDecision {
            chosen: Candidate::NoisyAnd,
            decided_by: Decided::Msac,
            candidates: vec![
                rep(Candidate::Geometry, 74, 900.0),
                rep(Candidate::NoisyAnd, 74, 880.5),
            ],
            ..d
        };
        assert!(
            d.provenance()
                .contains("chose noisy-and, 74 vs geometry 74")
                && d.provenance().contains("tie, MSAC 880.5 vs 900.0"),
            "{}",
            d.provenance()
        );
    }
}
