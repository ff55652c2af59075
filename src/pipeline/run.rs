//! The single run of one registration: the steps of a [`Plan`] in order, each filling its key
//! (the geometric branch alone here, the image branch's steps in `image_branch`), then the
//! in-memory tail. The scale search (`scales`) runs it once per hypothesis; the entry point is
//! [`Registration::run`] (`register.rs`).

use std::sync::Arc;

use super::geo::{cached_branch, geo_branches};
use super::graph::{Plan, StageName};
use super::memo::Memo;
use super::params::GeoFeatureSource;
use super::registration::Registration;
use super::result::RegistrationResult;
use super::stages::Ctx;
use super::tail::{fuse_and_finish, FusionInputs};
use crate::dataset::ScanPair;
use crate::error::{Error, Result};

impl Registration<'_> {
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
