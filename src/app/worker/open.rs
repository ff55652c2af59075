//! Opening data in the worker: a dataset (manifest, 3DMatch folder, RGB-D sequence, two
//! clouds) replaces the open one only once its first pair loads; a Cosmos output folder
//! switches the image branch to it.

use std::path::PathBuf;
use std::time::Instant;

use super::PipelineWorker;
use crate::app::channel::OpenKind;
use crate::app::channel::{EventSink, LogLevel, WorkerEvent};
use crate::cache::Cache;
use crate::dataset::manifest::Dataset;
use crate::dataset::ScanPair;
use crate::pipeline::manifest_settings::{adopt_preset, ManifestSettings};
use crate::pipeline::params::cosmos_output_settings;
use crate::pipeline::{RegisterParams, WfmSpec};
use crate::wfm::PromptPreset;

impl PipelineWorker {
    /// Turns what was opened into a dataset, loads its first pair (so a bad file fails here,
    /// with the previous dataset still loaded), then replaces the dataset and registers it.
    /// False when nothing was opened (the error is logged).
    pub(super) fn open(&mut self, kind: OpenKind, paths: Vec<PathBuf>, events: &EventSink) -> bool {
        let what = paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ");
        let kind = match kind {
            OpenKind::Auto => crate::dataset::open::classify_drop(&paths),
            k => k,
        };
        if kind == OpenKind::CosmosOutput {
            return self.open_cosmos_output(&paths, events);
        }
        let t = Instant::now();
        match crate::dataset::open::open_dataset(kind, &paths) {
            Ok(d) => {
                let d = d.with_fragment_cache(Cache::open(crate::cache::default_cache_dir()).ok());
                let first = d.pairs().first().map(|p| p.id.clone());
                let pre = match &first {
                    Some(id) => match d.load_pair(id) {
                        Ok(p) => Some(p),
                        Err(e) => {
                            events.log(
                                LogLevel::Error,
                                format!(
                                    "{what}: {e} (loading pair {id}; the previous dataset stays open)"
                                ),
                            );
                            return false;
                        }
                    },
                    None => None,
                };
                events.log(
                    LogLevel::Info,
                    format!(
                        "loaded {} in {:.0} ms",
                        first.as_deref().unwrap_or("(no pairs)"),
                        t.elapsed().as_secs_f64() * 1e3
                    ),
                );
                self.replace_dataset(d, pre, &what, events);
                true
            }
            Err(e) => {
                events.log(
                    LogLevel::Error,
                    format!("{e} (the previous dataset stays open)"),
                );
                false
            }
        }
    }

    /// A Cosmos output folder: the image branch switches to it (cached Cosmos backend, the
    /// folder + its JSONL spec, as the Image-branch controls set them), the dataset stays, and
    /// the current pair re-runs. False (logged) when the folder or its spec is unusable.
    fn open_cosmos_output(&mut self, paths: &[PathBuf], events: &EventSink) -> bool {
        let r = match paths {
            [dir] => cosmos_output_settings(&self.params, dir).and_then(|s| {
                // the spec must parse (positional mapping) before the settings change
                if let Some(WfmSpec::Cached { dir, spec }) = s.image.as_ref().map(|i| &i.backend) {
                    crate::wfm::cached::CachedBackend::open(dir, spec)?;
                }
                Ok(s)
            }),
            _ => Err(crate::Error::Usage(format!(
                "expected one Cosmos output folder, got {} paths",
                paths.len()
            ))),
        };
        let s = match r {
            Ok(s) => s,
            Err(e) => {
                events.log(
                    LogLevel::Error,
                    format!("{e} (the image branch settings stay as they were)"),
                );
                return false;
            }
        };
        if let Some(WfmSpec::Cached { dir, spec }) = s.image.as_ref().map(|i| &i.backend) {
            events.log(
                LogLevel::Info,
                format!(
                    "image branch: cached Cosmos output {} with spec {} (dataset unchanged)",
                    dir.display(),
                    spec.display()
                ),
            );
        }
        self.params = s.clone();
        events.send(WorkerEvent::Settings(Box::new(s)));
        let id = self
            .selected_pair()
            .or_else(|| self.pairs.first().map(|p| p.id.clone()));
        match id {
            Some(id) => self.run_and_report(&id, true, events),
            None => events.log(LogLevel::Warn, "the dataset lists no pairs"),
        }
        true
    }

    /// The settings the data `d` (named `what`) open with, from those in force, and the notices
    /// saying what changed: the protocol the manifest names for the first pair (indoor when
    /// none), resolved as `register` resolves it, so a preset chosen on other data is replaced
    /// (the Scale & success controls follow; edit them after); the geometric features it
    /// names; a scene-specific prompt that described the previous data's scene describes its.
    pub fn settings_for(
        &self,
        d: &Dataset,
        what: &str,
    ) -> (RegisterParams, Vec<(LogLevel, String)>) {
        let mut p = self.params.clone();
        let mut notices = Vec::new();
        let ms = match d.pairs().first() {
            Some(pair) => ManifestSettings::of_pair(d, &pair.id),
            None => ManifestSettings::of(d),
        };
        if let Some(n) = adopt_preset(&mut p, what, &ms) {
            notices.push((LogLevel::Warn, n));
        }
        if let Some(g) = ms.geo_features {
            if p.geo_features.descriptor() != Some(g) {
                p.geo_features = crate::pipeline::params::GeoFeatureSource::from(g);
                notices.push((
                    LogLevel::Warn,
                    format!(
                        "{what} names its geometric features: {} (Settings, \u{201c}Geometric \
                         features\u{201d})",
                        g.name()
                    ),
                ));
            }
        }
        let scene_of = |ds: &Dataset| {
            ds.scene_prompt
                .clone()
                .unwrap_or_else(|| PromptPreset::SceneSpecific.default_scene().to_owned())
        };
        let (old_scene, new_scene) = (scene_of(&self.dataset), scene_of(d));
        if let Some(ib) = p.image.as_mut() {
            if ib.prompt.scene.trim() == old_scene.trim() && old_scene != new_scene {
                ib.prompt.scene = new_scene;
                notices.push((
                    LogLevel::Info,
                    format!("{what}: the scene-specific prompt now describes its scene"),
                ));
            }
        }
        (p, notices)
    }

    fn replace_dataset(
        &mut self,
        d: Dataset,
        first: Option<ScanPair>,
        what: &str,
        events: &EventSink,
    ) {
        // the demo's protocol stays with the demo: the data opened now gets the user's
        // settings back (the controls follow)
        if let Some(user) = self.demo_user.take() {
            let mut restored = self.params.clone();
            restored.image = user.image.clone();
            restored.fusion.mode = user.fusion.mode;
            restored.fusion.selection = user.fusion.selection;
            if restored != self.params {
                events.log(
                    LogLevel::Warn,
                    "the demo's protocol (built-in frames, L = 8, m = 1, K = 2) stays with the \
                     demo: your own image-branch, fusion-mode and selection settings are back",
                );
                self.params = restored;
                events.send(WorkerEvent::Settings(Box::new(self.params.clone())));
            }
        }
        let (params, notices) = self.settings_for(&d, what);
        if params != self.params {
            for (level, n) in notices {
                events.log(level, n);
            }
            self.params = params;
            events.send(WorkerEvent::Settings(Box::new(self.params.clone())));
        }
        let params = self.params.clone();
        let cache = self.cache.take();
        // the models and file hashes stay valid across datasets
        let memo = std::mem::take(&mut self.memo);
        *self = Self::with_cache(d, params.clone(), cache, None);
        self.memo = memo;
        self.params = params;
        if let Some(p) = first {
            self.loaded.insert(p.id.clone(), p);
        }
        events.log(
            LogLevel::Info,
            format!("opened {what} ({} pairs)", self.pairs.len()),
        );
        match self.pairs.first().map(|p| p.id.clone()) {
            Some(id) => self.run_and_report(&id, true, events),
            None => events.log(LogLevel::Warn, "the dataset lists no pairs"),
        }
    }
}
