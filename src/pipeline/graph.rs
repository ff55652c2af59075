//! The stage graph's data, a leaf of the pipeline: [`StageName`] (the stages, their cache
//! folders and labels), [`Step`] and [`Plan`] (the ordered steps of one registration with their
//! keys), [`Plan::skeleton`] (the one place that says which stages a registration has) and
//! [`Plan::invalidated_by`]. Forming the keys before a run is `plan.rs`; running the steps is
//! `register.rs` and `image_branch.rs`.

use super::params::RegisterParams;
use crate::dataset::ScanPair;

/// The stages of one registration, in the order they run. Each stage's file exports its own
/// as `NAME`; timings ([`super::StageTiming::name`]) and plans are recorded by it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum StageName {
    /// Depth frames rendered for point-cloud-only scans (`virtual-frames`).
    VirtualFrames,
    /// Keypoints and geometric features of both scans (`geo-fpfh`, `geo-spinnet`, or learned
    /// features read from files).
    Geo,
    DepthVideo,
    Generation,
    /// In memory.
    ViewSelect,
    Lift,
    /// Per-image VFM descriptors of the selected views at their lifted pixels (`vfm-view`).
    Vfm,
    /// Per-keypoint image descriptors of a per-image VFM (`image-points`).
    ImagePoints,
    /// Per-keypoint descriptors of a pair-conditioned VFM (`image-points-pair`).
    PairVfm,
    /// Similarity, calibration, fusion, selection, estimation, metrics (in memory).
    Fusion,
}

impl StageName {
    pub const ALL: [StageName; 10] = [
        StageName::VirtualFrames,
        StageName::Geo,
        StageName::DepthVideo,
        StageName::Generation,
        StageName::ViewSelect,
        StageName::Lift,
        StageName::Vfm,
        StageName::ImagePoints,
        StageName::PairVfm,
        StageName::Fusion,
    ];

    /// The stage's name as its key carries it (the cache folder of a cached stage); each
    /// stage's file takes its `STAGE` from here (`geo-spinnet`, the other geometric stage, names
    /// its own).
    pub const fn key_name(self) -> &'static str {
        match self {
            StageName::VirtualFrames => "virtual-frames",
            StageName::Geo => "geo-fpfh",
            StageName::DepthVideo => "depth-video",
            StageName::Generation => "generation",
            StageName::ViewSelect => "view-selection",
            StageName::Vfm => "vfm-view",
            StageName::Lift => "lift",
            StageName::ImagePoints => "image-points",
            StageName::PairVfm => "image-points-pair",
            StageName::Fusion => "fusion",
        }
    }

    /// For people (the stage panel).
    pub fn label(self) -> &'static str {
        match self {
            StageName::VirtualFrames => "virtual frames",
            StageName::Geo => "geometric features",
            StageName::DepthVideo => "depth video",
            StageName::Generation => "generation",
            StageName::ViewSelect => "view selection",
            StageName::Vfm => "VFM views",
            StageName::Lift => "lift",
            StageName::ImagePoints => "image point features",
            StageName::PairVfm => "pair VFM point features",
            StageName::Fusion => "similarity, fusion and estimation",
        }
    }
}

/// One step of a plan: a stage and its key hashes (several for per-scan and per-view stages:
/// source before target). `keys` None: not known before an earlier step runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    pub stage: StageName,
    pub keys: Option<Vec<String>>,
}

/// The ordered steps of one registration of a pair under one parameter set, with their keys.
/// Two plans are equal when their steps (with their keys) and parameters are.
#[derive(Clone, Debug)]
pub struct Plan {
    pub(super) steps: Vec<Step>,
    /// The parameters the plan was made for.
    pub(super) params: RegisterParams,
    /// The steps a run has executed (the next one must be `steps[ran]`).
    pub(super) ran: usize,
}

impl PartialEq for Plan {
    fn eq(&self, other: &Plan) -> bool {
        self.steps == other.steps && self.params == other.params
    }
}

impl Plan {
    /// The steps of `pair` under `params`, no key known yet: the one place that says which
    /// stages a registration has.
    pub fn skeleton(pair: &ScanPair, params: &RegisterParams) -> Plan {
        let mut stages = Vec::new();
        match &params.image {
            None => stages.push(StageName::Geo),
            Some(ib) => {
                if pair.source.frames.is_none() || pair.target.frames.is_none() {
                    stages.push(StageName::VirtualFrames);
                }
                stages.push(StageName::Geo);
                // A frame-by-frame backend draws each view from its own depth frame: no video.
                if !ib.backend.frame_by_frame() {
                    stages.push(StageName::DepthVideo);
                }
                stages.extend([
                    StageName::Generation,
                    StageName::ViewSelect,
                    StageName::Lift,
                ]);
                if ib.vfm.is_pair_conditioned() {
                    stages.push(StageName::PairVfm);
                } else {
                    stages.extend([StageName::Vfm, StageName::ImagePoints]);
                }
            }
        }
        stages.push(StageName::Fusion);
        Plan {
            steps: stages
                .into_iter()
                .map(|stage| Step { stage, keys: None })
                .collect(),
            params: params.clone(),
            ran: 0,
        }
    }

    /// The steps in run order.
    pub fn steps(&self) -> &[Step] {
        &self.steps
    }

    /// The stages of this plan, in run order.
    pub fn stages(&self) -> impl Iterator<Item = StageName> + '_ {
        self.steps.iter().map(|s| s.stage)
    }

    /// The parameters the plan was made for.
    pub fn params(&self) -> &RegisterParams {
        &self.params
    }

    /// The key hashes of `stage`: None when the stage is not part of this plan or its key is
    /// not known yet.
    pub fn get(&self, stage: StageName) -> Option<&[String]> {
        self.steps
            .iter()
            .find(|s| s.stage == stage)
            .and_then(|s| s.keys.as_deref())
    }

    /// Whether `stage` is part of this plan and its key is known.
    pub fn is_known(&self, stage: StageName) -> bool {
        self.get(stage).is_some()
    }

    /// Whether every step's key is known (a plan a run has filled).
    pub fn is_complete(&self) -> bool {
        self.steps.iter().all(|s| s.keys.is_some())
    }

    /// The stages of `new` that must run again after `self`: their key differs, they were not
    /// part of `self`, or their key is not known before an earlier step runs. Earliest first.
    pub fn invalidated_by(&self, new: &Plan) -> Vec<StageName> {
        new.steps
            .iter()
            .filter(|s| s.keys.is_none() || self.get(s.stage) != s.keys.as_deref())
            .map(|s| s.stage)
            .collect()
    }

    /// A run executed the step of `stage` with `keys`. The run takes the plan's steps in
    /// order, each once: in debug builds (the tests) a step run out of order, twice, or not in
    /// the plan, and a key other than the one planned, are caught here.
    pub(crate) fn fill(&mut self, stage: StageName, keys: Vec<String>) {
        let next = self.steps.get(self.ran).map(|s| s.stage);
        debug_assert_eq!(next, Some(stage), "the run left the plan's order: {self:?}");
        if let Some(s) = self.steps.iter_mut().find(|s| s.stage == stage) {
            debug_assert!(
                s.keys.as_ref().is_none_or(|k| *k == keys),
                "{stage:?}: the step ran with another key than planned"
            );
            s.keys = Some(keys);
        }
        self.ran += 1;
    }

    /// A run starts: no step executed yet.
    pub(crate) fn start_run(&mut self) {
        self.ran = 0;
    }

    /// Whether a run has executed every step before the in-memory tail (the last step).
    pub(crate) fn ran_all_but_the_tail(&self) -> bool {
        self.ran + 1 == self.steps.len()
    }

    /// Sets a key known before the run ([`super::plan::plan`]).
    pub(crate) fn set(&mut self, stage: StageName, keys: Vec<String>) {
        if let Some(s) = self.steps.iter_mut().find(|s| s.stage == stage) {
            s.keys = Some(keys);
        }
    }
}
