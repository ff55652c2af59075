//! One pair at a time: load, register (the image branch through the stage cache), re-fuse
//! from memory after a change of the in-memory stages' settings, branch posteriors of a
//! clicked point, figure 7, and the report of a run to the UI.

use std::sync::Arc;
use std::time::Instant;

use super::model_build::{default_posterior_point, result_to_model};
use super::{invalidated_row, Current, Kept, PipelineWorker};
use crate::app::channel::{EventSink, LogLevel, WorkerEvent};
use crate::app::model::StageRole;
use crate::app::model::{
    InspectorModel, PairEntry, PairStatus, SettingsTag, StageInfo, StageState,
};
use crate::dataset::ScanPair;
use crate::pipeline::plan::{Plan, StageName};
use crate::pipeline::tail::{similarities, EstimateMemo, FusionInputs};
use crate::pipeline::{Registration, RegistrationResult};

/// What [`PipelineWorker::register`] gives: the result, the in-memory stages' inputs (for
/// re-fusion and posteriors), a note for the image-branch panel and the prompt whose
/// generation is missing.
pub(super) struct Registered {
    pub(super) result: RegistrationResult,
    pub(super) inputs: Arc<FusionInputs>,
    pub(super) note: Option<String>,
    pub(super) missing: Option<String>,
    /// The estimate of this run with its inputs: the first re-fusion that keeps them (a
    /// temperature change under NN selection) reuses it.
    pub(super) estimates: EstimateMemo,
}

impl PipelineWorker {
    /// Loads (or reuses) and registers one pair, generating views when needed; returns the
    /// model. Synchronous.
    pub fn run_pair(&mut self, id: &str) -> crate::Result<InspectorModel> {
        self.run_pair_with(id, true)
    }

    /// The kept geometric branch of a plan's pair (FPFH), from a run of this pair with the
    /// same clouds and voxel, and its timing row.
    fn kept_geometry(
        &mut self,
        plan: &Plan,
    ) -> Option<(Arc<FusionInputs>, crate::pipeline::StageTiming)> {
        let key = geo_memo_key(plan)?;
        self.geo.get(&key).map(|g| {
            let t = crate::pipeline::StageTiming {
                stage: "fpfh source + target (in memory)".into(),
                name: Some(StageName::Geo),
                ms: 0.0,
                status: "cached".into(),
            };
            (g.clone(), t)
        })
    }

    /// Keeps the geometric branch of `inputs` (FPFH) for geometry-only runs of the pair that
    /// `plan` ran.
    fn keep_geometry(&mut self, plan: Option<&Plan>, inputs: &FusionInputs) {
        let Some(key) = plan.and_then(geo_memo_key) else {
            return;
        };
        if !self.geo.contains_key(&key) {
            let g = Arc::new(FusionInputs {
                source_geo: inputs.source_geo.clone(),
                target_geo: inputs.target_geo.clone(),
                image: None,
                image_label: None,
                views: None,
            });
            self.geo.insert(key, g);
        }
    }

    /// [`run_pair`](Self::run_pair); with `generate` false a generation missing from the cache
    /// is not produced: the model says so (`generation_missing`) and shows no views.
    pub fn run_pair_with(&mut self, id: &str, generate: bool) -> crate::Result<InspectorModel> {
        let pair = match self.loaded.get(id) {
            Some(p) => p.clone(),
            None => {
                let p = self.dataset.load_pair(id)?;
                self.loaded.insert(id.to_string(), p.clone());
                p
            }
        };
        let params = self.params.clone();
        let invalidated = self.invalidated.take();
        let Registered {
            result,
            inputs,
            note,
            missing,
            estimates,
        } = self.register(id, &pair, generate)?;
        let label = self.fusion_label(&result);
        let mut model =
            result_to_model(&pair, &result, &label, self.pairs.clone(), &mut self.views);
        if params.image.is_some() {
            model.image_branch_note = note.clone();
        }
        model.generation_missing = missing.clone();
        self.stamp(&mut model, &params, &result);
        self.studies.fill(&mut model.plots);
        self.pairs = model.pairs.clone();
        if let Some(row) = invalidated {
            model.stages.insert(0, row);
        }
        // the plan the run filled: no key is computed again
        let kept = Some(Kept {
            plan: result.plan.clone(),
            sims: similarities(&inputs).ok().map(Arc::new),
            estimates,
            inputs,
            image: result.image.clone(),
            stages: model.stages.clone(),
            note: model.image_branch_note.clone(),
            generation_missing: missing,
        });
        self.current = Some(Current {
            pair,
            result,
            model,
            kept,
        });
        Ok(self.with_default_posterior())
    }

    /// Registers `pair` with the current parameters ([`Registration::run`] through the stage
    /// cache): the image branch when a WFM is chosen (an error when it cannot run: never a
    /// geometry-only result under its label), else the geometric branch alone, from memory
    /// when this pair's FPFH branch is kept. The one registration of the inspector: a single
    /// pair, "Run all" and the studies' rows all come from it.
    pub(super) fn register(
        &mut self,
        id: &str,
        pair: &ScanPair,
        generate: bool,
    ) -> crate::Result<Registered> {
        let params = self.params.clone();
        let mut note: Option<String> = None;
        let missing: Option<String> = None;
        let estimates = EstimateMemo::default();
        let cache = self.cache.clone();
        let fpfh = params.geo_features == crate::pipeline::params::GeoFeatureSource::Fpfh;
        // geometry only with FPFH: the plan (both scans' keys) says whether the branch is kept
        // (a scale search runs whole: its hypotheses have a plan each)
        let geo_plan = match (&params.image, fpfh && params.scales == 1) {
            (None, true) => Some(Registration::new(&params).memo(&self.memo).plan(pair)?),
            _ => None,
        };
        let kept = geo_plan.as_ref().and_then(|p| self.kept_geometry(p));
        let (result, inputs) = if let (Some((g, row)), Some(plan)) = (kept, geo_plan.clone()) {
            // geometry only, its branch kept from an earlier run of this pair: the tail alone
            let t0 = Instant::now();
            let reg = Registration::new(&params).estimates(&estimates);
            let mut r = reg.refuse_from_memory(pair, &g, None)?;
            r.timings.insert(0, row);
            r.total_ms = t0.elapsed().as_secs_f64() * 1e3;
            r.plan = Some(plan);
            (r, g)
        } else {
            if params.image.is_some() {
                if let Some(n) = self.cache_note.take() {
                    note = Some(n);
                }
            }
            // the image branch through the stage cache when a WFM is chosen, else the
            // geometric branch alone (FPFH and SpinNet through their cached stages)
            let reg = Registration::new(&params)
                .cache(cache.as_deref())
                .memo(&self.memo)
                .estimates(&estimates)
                .keep(true)
                .generate(generate);
            // A panic here reaches the worker thread's guard (`spawn_worker`), which reports it.
            let run = match geo_plan {
                Some(plan) => reg.run_plan(plan, pair),
                None => reg.run(pair),
            };
            let mut r = match (run, &params.image) {
                (Ok(r), _) => r,
                (Err(e), None) => return Err(e),
                // never a geometry-only result under an image-branch label: the pair is an
                // error with its reason (the UI offers the generator, or geometry alone)
                (Err(e @ crate::Error::GenerationNotCached { .. }), Some(_)) => return Err(e),
                (Err(e), Some(ib)) => {
                    return Err(crate::Error::Invalid(format!(
                        "the image branch cannot run for {id} (WFM: {}): {e}; nothing \
                         was registered (“Run geometry only” runs the geometric branch alone){}",
                        ib.backend.label(),
                        virtual_camera_hint(pair, ib)
                    )))
                }
            };
            let inputs = r.inputs.take().ok_or_else(|| {
                crate::Error::Missing("the registration kept no fusion inputs".into())
            })?;
            if fpfh {
                // its geometric branch serves later geometry-only runs of this pair
                self.keep_geometry(r.plan.as_ref(), &inputs);
            }
            (r, inputs)
        };
        if let Some(img) = &result.image {
            let asked = params
                .image
                .as_ref()
                .map(|ib| ib.prompt.text())
                .unwrap_or_default();
            // an empty provenance prompt: the backend used none (oracle)
            if !img.provenance.prompt.trim().is_empty()
                && img.provenance.prompt.trim() != asked.trim()
            {
                note = Some(format!(
                    "these views were generated with the prompt “{}”, not the one in the editor \
                     (the {} backend cannot regenerate them)",
                    img.provenance.prompt, img.provenance.backend
                ));
            }
        }
        Ok(Registered {
            result,
            inputs,
            note,
            missing,
            estimates,
        })
    }

    /// The current model with the posterior of [`default_posterior_point`] added (the
    /// posterior tab opens on it); the model unchanged when no posterior can be formed.
    fn with_default_posterior(&mut self) -> InspectorModel {
        let chosen = self
            .current
            .as_ref()
            .and_then(|c| default_posterior_point(&c.model.matches, c.model.gt_inlier_m));
        if let Some((src, why)) = chosen {
            if let Ok(m) = self.inspect_point(src) {
                if let Some(c) = self.current.as_mut() {
                    if let Some(p) = c
                        .model
                        .posteriors
                        .iter_mut()
                        .find(|p| p.source_point == src)
                    {
                        p.reason = why;
                    }
                    c.model.default_posterior = Some(src);
                    return c.model.clone();
                }
                return m;
            }
        }
        self.current
            .as_ref()
            .map(|c| c.model.clone())
            .unwrap_or_default()
    }

    /// Marks `model` (and the current pair's row) with the settings it was computed with and
    /// the branches that ran.
    pub(super) fn stamp(
        &self,
        model: &mut InspectorModel,
        params: &crate::pipeline::RegisterParams,
        result: &RegistrationResult,
    ) {
        let ran = branches_ran(params, result);
        stamp_model(
            model,
            SettingsTag::of(params),
            ran,
            self.demo_user.is_some(),
        );
    }

    fn fusion_label(&self, result: &RegistrationResult) -> String {
        match &result.image_branch {
            Some(_) => self.params.fusion.mode.label().to_string(),
            None => format!("geometry only ({}; image branch off)", result.geo_features),
        }
    }

    /// Re-runs similarity, fusion and estimation from memory when the current pair was run with
    /// the same image-branch settings (only calibration, fusion, selection or estimator
    /// changed). None: a full (cached) run is needed.
    pub fn refuse_from_memory(&mut self) -> Option<crate::Result<InspectorModel>> {
        let params = self.params.clone();
        let label_settings = self.params.fusion.mode;
        let cache = self.cache.clone();
        let cur = self.current.as_mut()?;
        let kept = cur.kept.as_ref()?;
        // Compare every stage's key under the new settings with the kept run's: the inputs in
        // memory serve only when nothing before fusion changed.
        let t0 = Instant::now();
        // From the kept plan when only fusion-stage settings changed (no cloud or frame hashed),
        // else one plan of the new settings.
        let new = match &kept.plan {
            Some(k) => k.replan(&cur.pair, &params, cache.as_deref(), &self.memo),
            None => crate::pipeline::plan(&cur.pair, &params, cache.as_deref(), &self.memo),
        }
        .ok();
        let changed = match (&kept.plan, &new) {
            (Some(old), Some(new)) => old.invalidated_by(new),
            _ => StageName::ALL.to_vec(),
        };
        let row = invalidated_row(&changed, t0.elapsed().as_secs_f64() * 1e3);
        // a scale search arbitrates between whole registrations: it always runs whole (from
        // the stage cache)
        if params.scales > 1 || changed.iter().any(|s| *s != StageName::Fusion) {
            self.invalidated = Some(row);
            return None;
        }
        // the re-fuse row times the re-fuse alone (the key comparison has its own row)
        let t0 = Instant::now();
        let run = Registration::new(&params)
            .estimates(&kept.estimates)
            .refuse_from_memory(&cur.pair, &kept.inputs, kept.sims.as_deref());
        let mut result = match run {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        result.image = kept.image.clone();
        let label = match &result.image_branch {
            Some(_) => label_settings.label().to_string(),
            None => format!("geometry only ({}; image branch off)", result.geo_features),
        };
        let mut model = result_to_model(
            &cur.pair,
            &result,
            &label,
            self.pairs.clone(),
            &mut self.views,
        );
        let mut stages: Vec<StageInfo> = kept
            .stages
            .iter()
            // the stages before the tail (not the tail's steps, nor the worker's own rows)
            .filter(|s| s.stage.is_some_and(|n| n != StageName::Fusion))
            .map(|s| StageInfo {
                name: s.name.clone(),
                stage: s.stage,
                state: StageState::Cached,
                time_ms: Some(0.0),
                role: StageRole::Part,
            })
            .collect();
        stages.append(&mut model.stages);
        // "re-fuse from memory" first: `report` adds no second row of that name
        stages.insert(
            0,
            StageInfo {
                name: "re-fuse from memory".into(),
                stage: None,
                state: StageState::Done,
                time_ms: Some(t0.elapsed().as_secs_f64() * 1e3),
                role: StageRole::Container,
            },
        );
        stages.insert(1, row);
        model.stages = stages;
        if result.image.is_some() || kept.note.is_some() {
            model.image_branch_note = kept.note.clone();
        }
        model.generation_missing = kept.generation_missing.clone();
        let (tag, ran) = (SettingsTag::of(&params), branches_ran(&params, &result));
        stamp_model(&mut model, tag, ran, self.demo_user.is_some());
        self.studies.fill(&mut model.plots);
        self.pairs = model.pairs.clone();
        cur.model = model;
        cur.result = result;
        // the next change is compared with these settings, not the first run's
        if let Some(k) = cur.kept.as_mut() {
            k.plan = new;
        }
        Some(Ok(self.with_default_posterior()))
    }

    pub(super) fn report(
        &mut self,
        id: &str,
        t: Instant,
        r: crate::Result<InspectorModel>,
        stage: &str,
        events: &EventSink,
    ) {
        match r {
            Ok(mut model) => {
                self.studies.fill(&mut model.plots);
                model.plots.figure7_pending = self.figure7_possible();
                model.scene_prompt = self.dataset.scene_prompt.clone();
                let ms = t.elapsed().as_secs_f64() * 1e3;
                if model.stages.first().is_none_or(|s| s.name != stage) {
                    model.stages.insert(
                        0,
                        StageInfo {
                            name: stage.into(),
                            stage: None,
                            state: StageState::Done,
                            time_ms: Some(ms),
                            role: StageRole::Container,
                        },
                    );
                }
                let msg = match model.current_pair.and_then(|i| model.pairs.get(i)) {
                    Some(PairEntry {
                        rre_deg: Some(r),
                        rte_m: Some(e),
                        ..
                    }) => format!(
                        "{id}: RRE {r:.2}° RTE {:.1} cm, {} matches, {ms:.0} ms ({stage})",
                        e * 100.0,
                        model.matches.len()
                    ),
                    _ => format!(
                        "{id}: registered, {} matches, {ms:.0} ms ({stage})",
                        model.matches.len()
                    ),
                };
                if let Some(c) = self.current.as_mut() {
                    c.model = model.clone();
                    for w in &c.result.warnings {
                        events.log(LogLevel::Warn, format!("{id}: {w}"));
                    }
                }
                events.log(LogLevel::Info, msg);
                if let Some(n) = &model.image_branch_note {
                    let level = if model.generation_missing.is_some()
                        || model.source_views.is_empty() && self.params.image.is_some()
                    {
                        LogLevel::Warn
                    } else {
                        LogLevel::Info
                    };
                    events.log(level, n.clone());
                }
                events.send(WorkerEvent::Model(Box::new(model)));
            }
            Err(e) => {
                let msg = format!("{id}: {e}");
                let tag = SettingsTag::of(&self.params);
                if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
                    p.reset(PairStatus::Failed(e.to_string()));
                    p.settings = Some(tag.clone());
                }
                let mut model = self.initial_model(Some(id));
                model.pairs = self.pairs.clone();
                if let Some(i) = model.current_pair {
                    model.pairs[i].status = PairStatus::Failed(e.to_string());
                }
                model.stages = vec![StageInfo {
                    name: stage.into(),
                    stage: None,
                    state: StageState::Failed(e.to_string()),
                    time_ms: Some(t.elapsed().as_secs_f64() * 1e3),
                    role: StageRole::Container,
                }];
                model.image_branch_note = Some(format!("registration failed: {e}"));
                if let crate::Error::GenerationNotCached { .. } = e {
                    model.generation_missing =
                        self.params.image.as_ref().map(|ib| ib.prompt.text());
                }
                model.settings = Some(tag);
                model.demo_protocol = self
                    .demo_user
                    .is_some()
                    .then(|| super::DEMO_PROTOCOL_NOTE.to_string());
                self.current = None;
                events.send(WorkerEvent::Model(Box::new(model)));
                events.log(LogLevel::Error, msg);
            }
        }
    }

    pub(super) fn run_and_report(&mut self, id: &str, generate: bool, events: &EventSink) {
        self.selected = Some(id.to_string());
        events.send(WorkerEvent::Stage(StageInfo {
            name: "load + register".into(),
            stage: None,
            state: StageState::Running,
            time_ms: None,
            role: StageRole::Container,
        }));
        if let Some(p) = self.pairs.iter_mut().find(|p| p.id == id) {
            p.status = PairStatus::Running;
        }
        let t = Instant::now();
        let r = self.run_pair_with(id, generate);
        self.report(id, t, r, "load + register", events);
    }
}

fn stamp_model(model: &mut InspectorModel, tag: SettingsTag, ran: String, demo: bool) {
    if let Some(row) = model.current_pair.and_then(|i| model.pairs.get_mut(i)) {
        row.settings = Some(tag.clone());
    }
    model.settings = Some(tag);
    model.branches_ran = Some(ran);
    model.demo_protocol = demo.then(|| super::DEMO_PROTOCOL_NOTE.to_string());
}

/// What ran for `result`: the geometric branch, and the image branch with its backend and VFM
/// when it did (from the result, not from the settings asked for).
pub fn branches_ran(
    params: &crate::pipeline::RegisterParams,
    result: &RegistrationResult,
) -> String {
    let geo = format!("geometry ({})", result.geo_features);
    match (result.image_branch_source(), &params.image) {
        (Some(img), _) => format!(
            "ran: {geo} + image ({img}), fused by {}",
            params.fusion.mode.label()
        ),
        (None, Some(_)) => format!("ran: {geo} only — the image branch asked for did not run"),
        (None, None) => format!("ran: {geo} only (image branch off)"),
    }
}

/// Where it matters, what the virtual camera choice does: a point-cloud-only scan without
/// intensity (KITTI's downsampled xyz scans) gets the pinhole camera under `auto`, which LiDAR
/// needs replaced by f-theta.
fn virtual_camera_hint(
    pair: &ScanPair,
    ib: &crate::pipeline::params::ImageBranchParams,
) -> &'static str {
    use crate::pipeline::params::VirtualCamera;
    let xyz_only = |s: &crate::dataset::Scan| s.frames.is_none() && s.cloud.intensity.is_none();
    if ib.virtual_camera == VirtualCamera::Auto
        && (xyz_only(&pair.source) || xyz_only(&pair.target))
    {
        "; a scan is a point cloud without intensity, so “auto” renders it with the pinhole \
         camera: for LiDAR (e.g. KITTI's xyz scans) choose the f-theta virtual camera (Views, \
         “Virtual camera”, or --virtual-camera ftheta)"
    } else {
        ""
    }
}

/// The worker's key of a pair's geometric branch: both scans' `geo-fpfh` stage keys (the
/// clouds' content and the voxel size) from the plan, so a reloaded pair with other points
/// is not served another's features.
fn geo_memo_key(plan: &Plan) -> Option<String> {
    plan.get(StageName::Geo).map(|k| k.join("+"))
}
