//! The registration entry point: a [`Registration`] (parameters, stage cache, the caller's
//! memo, what to keep; `registration.rs`) registers one pair with [`Registration::run`] (the
//! single run of `run.rs`, or the scale search of `scales.rs` above it), gives the plan ahead
//! with [`Registration::plan`], and re-runs the in-memory tail from kept inputs with
//! [`Registration::refuse_from_memory`]. The CLI (`register`, `bench`, `generate`), the
//! studies, the inspector's worker and the Python binding all register through it. The stages
//! are in `stages/`, which steps a registration has in `graph`, their keys before a run in
//! `plan`, the steps' execution in `run` and `image_branch`, the in-memory tail in `tail`.

pub use super::registration::Registration;

use super::graph::Plan;
use super::memo::Memo;
use super::result::RegistrationResult;
use super::tail::{fuse_and_finish, FusionInputs, Similarities};
use crate::dataset::ScanPair;
use crate::error::Result;

impl Registration<'_> {
    /// Register `pair`: the geometric branch (FPFH and SpinNet through their cached stages;
    /// features read from files have none), the image branch's stages when `params.image`
    /// is set, then the in-memory tail. With `keep`, the result holds the tail's inputs; it
    /// always holds the plan it ran with every key filled ([`RegistrationResult::plan`]).
    /// It runs the steps of [`Plan::skeleton`] (no key is computed twice).
    /// With `params.scales` > 1 it is the scale search ([`super::scales`]): this run at each
    /// hypothesis's voxel, the most visibility-consistent pose kept (its plan in the result).
    pub fn run(&self, pair: &ScanPair) -> Result<RegistrationResult> {
        if self.params.scales > 1 {
            return super::scales::register(self, pair);
        }
        self.run_plan(Plan::skeleton(pair, self.params), pair)
    }

    /// The plan of `pair` under these parameters: the steps [`Self::run`] takes, each with its
    /// key where it is known before anything runs (reads the cache, computes no stage).
    pub fn plan(&self, pair: &ScanPair) -> Result<Plan> {
        let own = Memo::default();
        super::plan::plan(pair, self.params, self.cache, self.memo.unwrap_or(&own))
    }

    /// The in-memory tail alone, from `inputs` kept by an earlier [`Self::run`] (its
    /// `result.inputs`): similarity, calibration, fusion, selection, estimation and
    /// evaluation under `params`, with the kept similarity matrices `sims` when given
    /// ([`super::tail::similarities`]; None computes them, the result is the same). What a
    /// change of temperature, fusion mode, selection or estimator re-runs. The result's
    /// `image` is None (the caller keeps the views) and so are its `inputs` (the caller has
    /// them).
    pub fn refuse_from_memory(
        &self,
        pair: &ScanPair,
        inputs: &FusionInputs,
        sims: Option<&Similarities>,
    ) -> Result<RegistrationResult> {
        fuse_and_finish(pair, self.params, inputs, sims, self.estimates)
    }
}
