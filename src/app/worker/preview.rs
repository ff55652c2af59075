//! The default fusion kept interactive: a change of the in-memory tail's settings (a
//! temperature, the calibration, the selection) under `visibility` re-estimates and re-scores
//! up to four poses (seconds), so the worker first shows the fast answer, Noisy-AND's pose at
//! the new settings from the kept similarities (a few hundred ms), saying it is a preview, and
//! refines it to the visibility rule's result when no other command is queued (a slider drag
//! shows a preview per value and refines the last one only).

use std::time::Instant;

use super::model_build::result_to_model;
use super::session::branches_ran;
use super::{PipelineWorker, DEMO_PROTOCOL_NOTE};
use crate::app::channel::{EventSink, LogLevel, WorkerEvent};
use crate::app::model::{
    InspectorModel, PairStatus, SettingsTag, StageInfo, StageRole, StageState,
};
use crate::fusion::FusionMode;
use crate::pipeline::plan::StageName;
use crate::pipeline::Registration;

/// What the preview says of itself (the pair header shows it until the refined result).
pub const PREVIEW_NOTE: &str = "preview: Noisy-AND's pose at the new settings (the fast \
     answer); the visibility rule is re-scoring its candidate poses and its result replaces \
     this";

impl PipelineWorker {
    /// The preview of the current settings when they change only the fusion stage of the kept
    /// run under `visibility`: Noisy-AND's re-fusion from the kept similarities, as a model whose
    /// pair row is still running. None: no preview applies (the full answer is as fast, or a
    /// run is needed).
    pub fn preview_refusion(&mut self) -> Option<crate::Result<InspectorModel>> {
        let params = self.params.clone();
        if params.fusion.mode != FusionMode::Visibility
            || params.scales > 1
            || params.image.is_none()
        {
            return None;
        }
        let cache = self.cache.clone();
        let cur = self.current.as_ref()?;
        let kept = cur.kept.as_ref()?;
        let old = kept.plan.as_ref()?;
        let new = old
            .replan(&cur.pair, &params, cache.as_deref(), &self.memo)
            .ok()?;
        if old.invalidated_by(&new) != [StageName::Fusion] {
            return None;
        }
        let t0 = Instant::now();
        let mut fast = params.clone();
        fast.fusion.mode = FusionMode::NoisyAnd;
        let run = Registration::new(&fast).refuse_from_memory(
            &cur.pair,
            &kept.inputs,
            kept.sims.as_deref(),
        );
        let mut result = match run {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        result.image = kept.image.clone();
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let mut model = result_to_model(
            &cur.pair,
            &result,
            FusionMode::NoisyAnd.label(),
            self.pairs.clone(),
            &mut self.views,
        );
        if let Some(i) = model.current_pair {
            model.pairs[i].status = PairStatus::Running;
            model.pairs[i].settings = Some(SettingsTag::of(&params));
        }
        model.stages = vec![
            StageInfo {
                name: "preview: Noisy-AND re-fused from memory".into(),
                stage: None,
                state: StageState::Done,
                time_ms: Some(ms),
                role: StageRole::Container,
            },
            StageInfo {
                name: "visibility rule: re-estimating and re-scoring its poses".into(),
                stage: Some(StageName::Fusion),
                state: StageState::Running,
                time_ms: None,
                role: StageRole::Stage,
            },
        ];
        model.image_branch_note = kept.note.clone();
        model.generation_missing = kept.generation_missing.clone();
        model.settings = Some(SettingsTag::of(&params));
        model.branches_ran = Some(branches_ran(&fast, &result));
        model.demo_protocol = self
            .demo_user
            .is_some()
            .then(|| DEMO_PROTOCOL_NOTE.to_string());
        model.preview_note = Some(PREVIEW_NOTE.to_string());
        model.scene_prompt = self.dataset.scene_prompt.clone();
        self.studies.fill(&mut model.plots);
        Some(Ok(model))
    }

    /// Sends the preview of a settings change when one applies and leaves the refinement for
    /// [`Self::refine`]; false when no preview applies.
    pub(super) fn send_preview(&mut self, id: &str, events: &EventSink) -> bool {
        let t = Instant::now();
        match self.preview_refusion() {
            Some(Ok(model)) => {
                events.log(
                    LogLevel::Info,
                    format!(
                        "{id}: preview (Noisy-AND) in {:.0} ms; refining with the visibility rule",
                        t.elapsed().as_secs_f64() * 1e3
                    ),
                );
                events.send(WorkerEvent::Model(Box::new(model)));
                self.refine = Some(id.to_string());
                true
            }
            // the full re-fusion reports the error
            Some(Err(_)) | None => false,
        }
    }

    /// The refinement a preview left: the settings' own re-fusion (or run) of its pair. False
    /// when none is pending.
    pub(super) fn refine(&mut self, events: &EventSink) -> bool {
        let Some(id) = self.refine.take() else {
            return false;
        };
        let t = Instant::now();
        match self.refuse_from_memory() {
            Some(r) => self.report(&id, t, r, "re-fuse from memory", events),
            None => self.run_and_report(&id, true, events),
        }
        true
    }
}
