//! What the worker derives from the current pair on request: the correspondence export and
//! the estimator's ranked hypotheses (both computed by the library).

use std::path::Path;

use super::PipelineWorker;
use crate::app::model::HypothesisList;
use crate::app::model::InspectorModel;

impl PipelineWorker {
    /// Writes the current pair's selected correspondences to `path` (an `.npz`, see
    /// [`crate::pipeline::export`]) from the kept fusion inputs; returns how many.
    pub fn export_correspondences(&self, path: &Path) -> crate::Result<usize> {
        let cur = self
            .current
            .as_ref()
            .ok_or_else(|| crate::Error::Invalid("no registered pair to export".into()))?;
        let kept = cur.kept.as_ref().ok_or_else(|| {
            crate::Error::Invalid("the fusion inputs of this pair were not kept".into())
        })?;
        let t = crate::pipeline::export::export_correspondences(
            path,
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
            .ok_or_else(|| crate::Error::Invalid("no registered pair".into()))?;
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
