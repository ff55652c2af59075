//! The registration entry point: a [`Registration`] (parameters, stage cache, the caller's
//! memo, what to keep) registers one pair with [`Registration::run`] (plan, then run the
//! plan's steps; [`Registration::plan`] gives the plan ahead), and re-runs the in-memory tail
//! from kept inputs with [`Registration::refuse_from_memory`]. The CLI (`register`, `bench`,
//! `generate`), the studies, the inspector's worker and the Python binding all register
//! through it. The stages are in `stages/`, which steps a registration has and their keys in
//! `plan`, the steps' execution in `image_branch` and `register_geometry` below, the
//! in-memory tail in `tail`.

use std::sync::Arc;

use super::geo::{cached_branch, geo_branches};
use super::memo::Memo;
use super::params::{GeoFeatureSource, RegisterParams};
use super::plan::{Plan, StageName};
use super::result::RegistrationResult;
use super::stages::Ctx;
use super::tail::{fuse_and_finish, EstimateMemo, FusionInputs, Similarities};
use crate::cache::Cache;
use crate::dataset::ScanPair;
use crate::error::{Error, Result};

/// One registration's settings and what it may reuse: register `pair.source` onto
/// `pair.target` with [`Self::run`]: the geometric branch, plus the image branch when
/// `params.image` is set, then similarity, fusion, estimation and evaluation.
///
/// For example `Registration::new(&params).cache(&cache).memo(&memo).run(&pair)?` (the
/// builder methods set the public fields below).
#[derive(Clone, Copy)]
pub struct Registration<'a> {
    /// Everything the registration computes with (the image branch when `params.image` is set).
    pub params: &'a RegisterParams,
    /// The stage cache the cached stages (`geo-fpfh`, `geo-spinnet`, the image branch's)
    /// read from and write to; None computes every stage in memory.
    pub cache: Option<&'a Cache>,
    /// The caller's memo (file hashes, loaded models): a caller of many pairs keeps one, so
    /// each model loads once. None: a memo for this call only.
    pub memo: Option<&'a Memo>,
    /// The last estimate and its inputs: an estimate whose correspondences and estimator are
    /// those of the memo's last one is taken from it (the same result; its timing row says
    /// "cached"). The inspector keeps one per pair for its re-fusions. None: always estimated.
    pub estimates: Option<&'a EstimateMemo>,
    /// Keep the in-memory tail's inputs in the result ([`RegistrationResult::inputs`]): what
    /// a re-fusion, the correspondence export and the posterior inspector recompute from.
    pub keep: bool,
    /// Produce a generation missing from the cache (the default). False: the run fails with
    /// [`Error::GenerationNotCached`] instead (the inspector then offers to run the generator;
    /// `cgenreg generate` produces them in batches first).
    pub generate: bool,
}

impl<'a> Registration<'a> {
    /// A registration under `params`, everything computed in memory, nothing kept.
    pub fn new(params: &'a RegisterParams) -> Self {
        Registration {
            params,
            cache: None,
            memo: None,
            estimates: None,
            keep: false,
            generate: true,
        }
    }

    /// With the stage cache `cache` (`&Cache` or `Option<&Cache>`).
    pub fn cache(self, cache: impl Into<Option<&'a Cache>>) -> Self {
        Registration {
            cache: cache.into(),
            ..self
        }
    }

    /// With the caller's memo.
    pub fn memo(self, memo: &'a Memo) -> Self {
        Registration {
            memo: Some(memo),
            ..self
        }
    }

    /// With the caller's estimate memo.
    pub fn estimates(self, estimates: &'a EstimateMemo) -> Self {
        Registration {
            estimates: Some(estimates),
            ..self
        }
    }

    /// Keeping (true) the in-memory tail's inputs in the result.
    pub fn keep(self, keep: bool) -> Self {
        Registration { keep, ..self }
    }

    /// Producing (true) or refusing (false) a generation missing from the cache.
    pub fn generate(self, generate: bool) -> Self {
        Registration { generate, ..self }
    }

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

    /// Runs the steps of `plan` (made for `pair` under these parameters, by [`Self::plan`] or
    /// [`Plan::skeleton`]) in order, each filling its key; the result carries the filled plan.
    /// Crate-internal: [`Self::run`] is the public way in (the inspector's worker runs the plan
    /// it made to find its kept geometric branch).
    pub(crate) fn run_plan(&self, mut plan: Plan, pair: &ScanPair) -> Result<RegistrationResult> {
        if self.params.scales > 1 {
            return Err(Error::Invalid(
                "a scale search runs through Registration::run (one plan per hypothesis)".into(),
            ));
        }
        if plan.params() != self.params {
            return Err(Error::Invalid(
                "the plan was made for other parameters than the registration's".into(),
            ));
        }
        plan.start_run();
        let own;
        let memo = match self.memo {
            Some(m) => m,
            None => {
                own = Memo::default();
                &own
            }
        };
        let (mut result, inputs) = match &self.params.image {
            Some(ib) => super::image_branch::register_with_image(pair, self, ib, memo, &mut plan)?,
            None => register_geometry(pair, self, memo, &mut plan)?,
        };
        debug_assert!(plan.ran_all_but_the_tail(), "a step did not run: {plan:?}");
        plan.fill_fusion()?;
        debug_assert!(plan.is_complete(), "a step left its key unfilled: {plan:?}");
        result.plan = Some(plan);
        if self.keep {
            result.inputs = Some(Arc::new(inputs));
        }
        Ok(result)
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

/// The geometric branch alone: keypoints and features (FPFH and SpinNet through their cached
/// stages, as with the image branch), then the shared tail with no image descriptors.
fn register_geometry(
    pair: &ScanPair,
    reg: &Registration,
    memo: &Memo,
    plan: &mut Plan,
) -> Result<(RegistrationResult, FusionInputs)> {
    let params = reg.params;
    let mut ctx = Ctx::new(reg.cache, memo);
    // FPFH and SpinNet through their cached stages; features read from files have none
    let (src, tgt) = match params.geo_features {
        GeoFeatureSource::Fpfh | GeoFeatureSource::Spinnet { .. } => {
            let (s, sk) = cached_branch(&mut ctx, "source", &pair.source, params)?;
            let (t, tk) = cached_branch(&mut ctx, "target", &pair.target, params)?;
            plan.fill(StageName::Geo, vec![sk.hash, tk.hash]);
            (s, t)
        }
        _ => {
            plan.fill(StageName::Geo, super::plan::learned_geo_keys(params)?);
            geo_branches(pair, params, &mut ctx.timer)?
        }
    };
    if src.features.dim != tgt.features.dim {
        return Err(Error::Shape(format!(
            "source features are {}-D but target features are {}-D",
            src.features.dim, tgt.features.dim
        )));
    }
    let inputs = FusionInputs {
        source_geo: src,
        target_geo: tgt,
        image: None,
        image_label: None,
        views: None,
    };
    let mut res = fuse_and_finish(pair, params, &inputs, None, reg.estimates)?;
    let Ctx {
        timer, warnings, ..
    } = ctx;
    let mut timings = timer.timings;
    timings.append(&mut res.timings);
    res.timings = timings;
    res.total_ms = timer.t0.elapsed().as_secs_f64() * 1e3;
    res.warnings.extend(warnings);
    Ok((res, inputs))
}
