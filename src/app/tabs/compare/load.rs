//! The two runs of a comparison: read from bench JSONs, or run here over the open dataset
//! with two settings (see [`super::settings_run`]).

use std::path::{Path, PathBuf};

use super::{file_name, Side};
use crate::pipeline::params::RegisterParams;
use crate::report::compare::{self, compare, load_bench_run, BenchRun, Comparison};

/// One run as the panel shows it.
#[derive(Clone, Debug)]
pub struct LoadedRun {
    /// The bench JSON it was read from (None: run here, over the open dataset).
    pub path: Option<PathBuf>,
    /// The file's name, or "settings A" / "settings B".
    pub name: String,
    pub run: BenchRun,
    /// The run's parameters as the pipeline's type, or why they cannot be rebuilt.
    pub params: Result<RegisterParams, String>,
    /// The run's manifest, found here (see [`BenchRun::resolve_manifest`]).
    pub manifest: Option<PathBuf>,
    /// "FPFH (voxel 5 cm) | no image branch | geometry only | NN | SC2-PCR".
    pub summary: String,
    /// Files the settings name that are missing here (e.g. the VFM model of another machine).
    pub missing: Vec<PathBuf>,
}

/// Two runs and their comparison.
#[derive(Clone, Debug)]
pub struct LoadedComparison {
    pub a: LoadedRun,
    pub b: LoadedRun,
    pub comparison: Comparison,
}

impl LoadedComparison {
    pub fn run(&self, side: Side) -> &LoadedRun {
        match side {
            Side::A => &self.a,
            Side::B => &self.b,
        }
    }
}

fn loaded_run(path: &Path) -> Result<LoadedRun, String> {
    let run = load_bench_run(path).map_err(|e| e.to_string())?;
    let params = run.register_params().map_err(|e| e.to_string());
    let missing = params
        .as_ref()
        .map(compare::missing_files)
        .unwrap_or_default();
    Ok(LoadedRun {
        path: Some(path.to_path_buf()),
        name: file_name(path),
        manifest: run.resolve_manifest(path),
        summary: run.settings_summary(),
        params,
        missing,
        run,
    })
}

/// Reads two bench JSONs and compares them (B against A). Errors name the file and the field.
pub fn load_comparison(a: &Path, b: &Path) -> Result<LoadedComparison, String> {
    let a = loaded_run(a)?;
    let b = loaded_run(b)?;
    let comparison = compare(&a.run, &b.run);
    Ok(LoadedComparison { a, b, comparison })
}

/// A run made here with `params` (the worker's rows over the open dataset, as a bench run).
pub fn settings_run(name: &str, run: BenchRun, params: RegisterParams) -> LoadedRun {
    LoadedRun {
        path: None,
        name: name.to_string(),
        manifest: run.manifest.as_ref().map(PathBuf::from),
        summary: compare::settings_summary(&params),
        missing: compare::missing_files(&params),
        params: Ok(params),
        run,
    }
}

/// Two runs made here, compared (B against A).
pub fn settings_comparison(a: LoadedRun, b: LoadedRun) -> LoadedComparison {
    let comparison = compare(&a.run, &b.run);
    LoadedComparison { a, b, comparison }
}
