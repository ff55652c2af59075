//! What one registration uses and may reuse, as data: [`Registration`] (the parameters, the
//! stage cache, the caller's memo, what to keep) and its builder. The single run is `run.rs`,
//! the scale search above it `scales.rs`, the entry point ([`Registration::run`]) `register.rs`.

use super::memo::Memo;
use super::params::RegisterParams;
use super::tail::EstimateMemo;
use crate::cache::Cache;

/// One registration's settings and what it may reuse: register `pair.source` onto
/// `pair.target` with `Self::run`: the geometric branch, plus the image branch when
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
    /// Keep the in-memory tail's inputs in the result (`RegistrationResult::inputs`): what
    /// a re-fusion, the correspondence export and the posterior inspector recompute from.
    pub keep: bool,
    /// Produce a generation missing from the cache (the default). False: the run fails with
    /// `Error::GenerationNotCached` instead (the inspector then offers to run the generator;
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
}
