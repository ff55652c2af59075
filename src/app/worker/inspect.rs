//! What the worker derives from the current pair on request: the branch posteriors of a
//! clicked point, figure 7's precision-recall curves, the correspondence export and the
//! estimator's ranked hypotheses (all computed by the library).

use std::path::Path;
use std::sync::Arc;

use super::model_build::{point_posterior, pr_curve, FIGURE7_CORRECT_M};
use super::PipelineWorker;
use crate::app::channel::{EventSink, WorkerEvent};
use crate::app::model::{Branch, HypothesisList, InspectorModel, MatchInfo, PrCurve};
use crate::fusion::fuse::FusionMode;
use crate::pipeline::tail::similarities;

impl PipelineWorker {
    /// Adds the branch posteriors of source keypoint `src` to the current model.
    pub fn inspect_point(&mut self, src: usize) -> crate::Result<InspectorModel> {
        let fusion = self.params.fusion;
        let cur = self
            .current
            .as_mut()
            .ok_or_else(|| crate::Error::Missing("no registered pair to inspect".into()))?;
        if src >= cur.result.source_keypoints.len() {
            return Err(crate::Error::Invalid(format!(
                "point {src} is a display point, not a keypoint (keypoints: 0..{}); click a matched point",
                cur.result.source_keypoints.len()
            )));
        }
        let kept = cur.kept.as_ref().ok_or_else(|| {
            crate::Error::Invalid(
                "posteriors are computed for FPFH features only in this build".into(),
            )
        })?;
        let survived = cur
            .model
            .matches
            .iter()
            .find(|m| m.src == src)
            .and_then(|m| m.survived);
        let sims = match &kept.sims {
            Some(s) => s.clone(),
            None => Arc::new(similarities(&kept.inputs)?),
        };
        let post = point_posterior(
            &kept.inputs,
            &sims,
            kept.image.as_ref(),
            &fusion,
            src,
            cur.pair.gt_target_from_source.as_ref(),
            survived,
        )?;
        let mut post = post;
        post.reason = "chosen by click".into();
        cur.model.posteriors.retain(|p| p.source_point != src);
        cur.model.posteriors.push(post);
        Ok(cur.model.clone())
    }

    /// The paper's figure 7: precision-recall of the fused matches under Noisy-AND and under
    /// Noisy-OR (a match is correct within 5 cm under the ground truth, as in appendix D), from
    /// the kept similarities with the current calibration and selection. None without the
    /// image branch or ground truth.
    pub fn fusion_pr_curves(&self) -> Option<Vec<PrCurve>> {
        let cur = self.current.as_ref()?;
        let kept = cur.kept.as_ref()?;
        let sims = kept.sims.as_ref()?;
        let (s_img, vs, vt) = sims.image.as_ref()?;
        let gt = cur.pair.gt_target_from_source?;
        let params = self.params.clone();
        let sk = &kept.inputs.source_geo.keypoints.points;
        let tk = &kept.inputs.target_geo.keypoints.points;
        let curves: Vec<PrCurve> = [
            (FusionMode::NoisyAnd, "Noisy-AND"),
            (FusionMode::NoisyOr, "Noisy-OR"),
        ]
        .into_iter()
        .filter_map(|(mode, name)| {
            let mut f = params.fusion;
            f.mode = mode;
            let corr = crate::fusion::match_then_fuse_select(
                Some((s_img, Some(vs.as_slice()), Some(vt.as_slice()))),
                Some(&sims.geo),
                &f,
            )
            .ok()?;
            let matches: Vec<MatchInfo> = corr
                .iter()
                .filter_map(|c| {
                    let (sp, tp) = (sk.get(c.src as usize)?, tk.get(c.tgt as usize)?);
                    let d = (gt * sp.cast::<f64>() - tp.cast::<f64>()).norm();
                    Some(MatchInfo {
                        src: c.src as usize,
                        tgt: c.tgt as usize,
                        score: c.score,
                        inlier_gt: Some(d < FIGURE7_CORRECT_M),
                        branch: Branch::Both,
                        survived: None,
                    })
                })
                .collect();
            pr_curve(&format!("{name} ({} matches)", matches.len()), &matches)
        })
        .collect();
        (curves.len() == 2).then_some(curves)
    }

    /// Whether [`Self::fusion_pr_curves`] has what it needs (kept image similarity, GT).
    pub(super) fn figure7_possible(&self) -> bool {
        self.current.as_ref().is_some_and(|c| {
            c.pair.gt_target_from_source.is_some()
                && c.kept
                    .as_ref()
                    .and_then(|k| k.sims.as_ref())
                    .is_some_and(|s| s.image.is_some())
        })
    }

    /// Puts both figure-7 curves into the current model and sends it, once per model.
    pub(super) fn send_figure7(&mut self, events: &EventSink) {
        if !self
            .current
            .as_ref()
            .is_some_and(|c| c.model.plots.figure7_pending)
        {
            return;
        }
        let curves = self.fusion_pr_curves();
        if let Some(c) = self.current.as_mut() {
            c.model.plots.figure7_pending = false;
            if let Some(curves) = curves {
                c.model.plots.pr_curves = curves;
            }
            events.send(WorkerEvent::Model(Box::new(c.model.clone())));
        }
    }
    /// Writes the current pair's selected correspondences to `path` (an `.npz`, see
    /// [`crate::pipeline::export`]) from the kept fusion inputs; returns how many.
    pub fn export_correspondences(&self, path: &Path) -> crate::Result<usize> {
        let cur = self
            .current
            .as_ref()
            .ok_or_else(|| crate::Error::Missing("no registered pair to export".into()))?;
        let kept = cur.kept.as_ref().ok_or_else(|| {
            crate::Error::Missing("the fusion inputs of this pair were not kept".into())
        })?;
        // the save dialog asked before replacing a file: that is the user's --force
        let t = crate::pipeline::export::export_correspondences(
            path,
            true,
            &cur.pair,
            &self.params,
            &kept.inputs,
            kept.sims.as_deref(),
            &cur.result,
        )?;
        Ok(t.len())
    }

    /// Adds the estimator's ranked hypotheses to the current model (an explanation instead
    /// when there are none or they could not be formed).
    pub fn hypotheses(&mut self) -> crate::Result<InspectorModel> {
        let params = self.params.clone();
        let cur = self
            .current
            .as_mut()
            .ok_or_else(|| crate::Error::Missing("no registered pair".into()))?;
        // a scale search's result is the kept hypothesis's registration: its estimator ran at
        // that voxel
        let params = match &cur.result.scales {
            Some(s) => crate::pipeline::scales::hypothesis_params(&params, s.chosen_voxel),
            None => params,
        };
        let list = match crate::pipeline::hypotheses::estimator_hypotheses(
            &cur.result,
            &params,
            cur.pair.gt_target_from_source.as_ref(),
            crate::estimate::hypotheses::DEFAULT_TOP_N,
        ) {
            Ok(Some(r)) => HypothesisList::from_ranked(&r),
            Ok(None) => HypothesisList::none(format!(
                "{} forms no hypotheses: one least-squares solution",
                cur.result.estimator
            )),
            Err(e) => HypothesisList::none(format!("no hypotheses: {e}")),
        };
        cur.model.hypotheses = Some(list);
        Ok(cur.model.clone())
    }
}
