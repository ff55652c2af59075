//! K sweeps and prompt studies over the open dataset (figures 6 and 4), with progress and
//! Cancel between pairs, and the plots they leave in every model.

use std::time::Instant;

use super::PipelineWorker;
use crate::app::channel::{EventSink, LogLevel, StudyRequest, WorkerEvent};
use crate::app::model::{InspectorModel, KPoint, PlotData, PromptBar};
use crate::pipeline::study::{
    k_settings, prompt_settings, run_study_with, StudyReport, StudySetting,
};
use crate::pipeline::ImageBranchParams;

/// What the plots panel shows of the studies run on the open dataset.
#[derive(Clone, Debug, Default)]
pub(super) struct StudyPlots {
    vs_k: Vec<KPoint>,
    vs_k_source: String,
    prompt: Vec<PromptBar>,
    prompt_source: String,
}

impl StudyPlots {
    pub(super) fn fill(&self, plots: &mut PlotData) {
        plots.vs_k = self.vs_k.clone();
        plots.vs_k_source = self.vs_k_source.clone();
        plots.prompt_study = self.prompt.clone();
        plots.prompt_source = self.prompt_source.clone();
        plots.study_progress = None;
    }
}

/// `s` with every absolute path cut to its file name (titles and saved figures name no
/// machine's folders).
fn without_dirs(s: &str) -> String {
    s.split(' ')
        .map(|w| {
            let core = w.trim_matches(|c: char| "()[],;".contains(c));
            if core.starts_with('/') && core.len() > 1 {
                let name = std::path::Path::new(core)
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                w.replace(core, &name)
            } else {
                w.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// The plots of a study report: one point / bar per setting that ran at least one pair.
fn study_plots(rep: &StudyReport) -> (Vec<KPoint>, Vec<PromptBar>) {
    let ran = || {
        rep.rows
            .iter()
            .filter(|r| r.setting_skipped.is_none() && r.pairs_run > 0)
    };
    let k = ran()
        .map(|r| KPoint {
            k: r.k,
            rre_deg: r.rre_mean_deg.unwrap_or(f64::NAN),
            rte_m: r.rte_mean_m.unwrap_or(f64::NAN),
            pairs: r.pairs_run,
            skipped: r.skipped.len() + r.failed.len(),
            recall: r.recall,
        })
        .collect();
    let p = ran()
        .map(|r| PromptBar {
            category: r.setting.clone(),
            rre_deg: r.rre_mean_deg.unwrap_or(f64::NAN),
            rte_m: r.rte_mean_m.unwrap_or(f64::NAN),
            pairs: r.pairs_run,
            skipped: r.skipped.len() + r.failed.len(),
            recall: r.recall,
        })
        .collect();
    (k, p)
}

impl PipelineWorker {
    /// The settings of a study request: K values, or the four prompt presets with the editor's
    /// prefix plus the editor's scene as "custom" when it is none of the presets.
    pub fn study_settings(&self, req: &StudyRequest) -> Vec<StudySetting> {
        match req {
            StudyRequest::K(ks) => k_settings(ks),
            StudyRequest::Prompt => {
                let prompt = self
                    .params
                    .image
                    .as_ref()
                    .map(|ib| ib.prompt.clone())
                    .unwrap_or_else(|| ImageBranchParams::default().prompt);
                let scene = prompt.scene.trim();
                let own = self.dataset.scene_prompt.as_deref();
                let custom = (crate::wfm::PromptPreset::of_scene(scene).is_none()
                    && own.is_none_or(|o| o.trim() != scene))
                .then_some(scene);
                prompt_settings(prompt.prefix.trim(), own, custom)
            }
        }
    }

    /// Runs a study over every pair of the open dataset with the current settings (through
    /// the stage cache; a generation is produced when missing except for a Cosmos command),
    /// reporting progress, and keeps its plots. Synchronous (the worker thread).
    pub fn run_study(
        &mut self,
        req: &StudyRequest,
        progress: &mut dyn FnMut(usize, usize),
    ) -> crate::Result<StudyReport> {
        let params = self.params.clone();
        let settings = self.study_settings(req);
        let generate = params.generates_missing();
        let ids = self.pair_ids();
        let (loaded, dataset) = (&self.loaded, &self.dataset);
        let rep = run_study_with(
            &ids,
            &mut |id| match loaded.peek(id) {
                Some(p) => Ok(p.clone()),
                None => dataset.load_pair(id),
            },
            &params,
            &settings,
            self.cache.as_deref(),
            &self.memo,
            generate,
            &mut |p| progress(p.done, p.total),
            Some(&self.cancel),
        )?;
        let (k, p) = study_plots(&rep);
        let runs: usize = rep.rows.iter().map(|r| r.pairs_run).sum();
        let mut source = format!("{} · {} pairs", without_dirs(&rep.label()), rep.pairs.len());
        // a setting that ran no pair has no point: the title says so and why
        let dropped: Vec<String> = rep
            .rows
            .iter()
            .filter(|r| r.setting_skipped.is_some() || r.pairs_run == 0)
            .map(|r| match &r.setting_skipped {
                Some(why) => format!("{} ({why})", r.setting),
                None => format!("{} (no pair ran)", r.setting),
            })
            .collect();
        if !dropped.is_empty() {
            source.push_str(&format!(" · not plotted: {}", dropped.join("; ")));
        }
        match req {
            StudyRequest::K(_) => {
                self.studies.vs_k = k;
                self.studies.vs_k_source = if runs == 0 {
                    format!("no pair ran ({source})")
                } else {
                    source
                };
            }
            StudyRequest::Prompt => {
                self.studies.prompt = p;
                self.studies.prompt_source = if runs == 0 {
                    format!("no pair ran ({source})")
                } else {
                    source
                };
            }
        }
        Ok(rep)
    }

    pub(super) fn study(&mut self, req: StudyRequest, events: &EventSink) {
        let what = match &req {
            StudyRequest::K(_) => "K sweep",
            StudyRequest::Prompt => "prompt study",
        };
        if self.params.image.is_none() {
            events.log(
                LogLevel::Warn,
                format!("{what}: choose a WFM under “Image branch” first (a study needs the image branch)"),
            );
            return;
        }
        events.log(
            LogLevel::Info,
            format!(
                "{what}: {} pairs with the current settings…",
                self.pairs.len()
            ),
        );
        let t = Instant::now();
        self.cancel
            .store(false, std::sync::atomic::Ordering::Relaxed);
        let r = self.run_study(&req, &mut |done, total| {
            events.send(WorkerEvent::Progress(what.to_string(), done, total))
        });
        match r {
            Ok(rep) => {
                for row in &rep.rows {
                    if let Some(why) = &row.setting_skipped {
                        events.log(
                            LogLevel::Warn,
                            format!("{what}: {} skipped: {why}", row.setting),
                        );
                    }
                    for n in row.skipped.iter().chain(&row.failed) {
                        events.log(
                            LogLevel::Warn,
                            format!("{what}: {} · {}: {}", row.setting, n.pair_id, n.reason),
                        );
                    }
                    if let (Some(r), Some(e)) = (row.rre_mean_deg, row.rte_mean_m) {
                        events.log(
                            LogLevel::Info,
                            format!(
                                "{what}: {}: mean RRE {r:.2}° RTE {:.1} cm over {} pairs",
                                row.setting,
                                e * 100.0,
                                row.pairs_run
                            ),
                        );
                    }
                }
                for n in &rep.notes {
                    events.log(LogLevel::Warn, format!("{what}: {n}"));
                }
                events.log(
                    LogLevel::Info,
                    format!(
                        "{what} done in {:.1} s ({})",
                        t.elapsed().as_secs_f64(),
                        rep.label()
                    ),
                );
            }
            Err(e) => events.log(LogLevel::Error, format!("{what}: {e}")),
        }
        events.send(WorkerEvent::Progress(what.to_string(), 1, 1));
        let mut model = match &self.current {
            Some(c) => c.model.clone(),
            None => InspectorModel::default(),
        };
        model.pairs = self.pairs.clone();
        self.studies.fill(&mut model.plots);
        if let Some(c) = self.current.as_mut() {
            c.model = model.clone();
        }
        events.send(WorkerEvent::Model(Box::new(model)));
    }
}
