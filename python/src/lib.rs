//! `cgenreg._cgenreg`: the Python extension. Thin: every function calls the library's own
//! entry point (`cli::register_with_options`, `pipeline::geo::fpfh_branch`,
//! `fusion::match_then_fuse_select`, `estimate::estimate_pose`, `io::cloud`), with the
//! settings parsed by the command line's own parser, and releases the GIL while it computes.
//! The Python layer (`python/cgenreg/*.py`) turns keyword arguments into those options.

use cgenreg::cli::{PairInput, Registered};
use cgenreg::dataset::{Scan, ScanPair};
use cgenreg::features::Features;
use cgenreg::geometry::PointCloud;
use nalgebra::Point3;
use numpy::ndarray::{Array1, Array2};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyKeyboardInterrupt, PyMemoryError, PyRuntimeError};
use pyo3::prelude::*;
use std::path::PathBuf;

// A C-contiguous (N, 3) float32 array is read as `&[Point3<f32>]` in place: nalgebra's
// `Point3<f32>` is `#[repr(C)]` over `[f32; 3]` (checked here at compile time).
const _: () =
    assert!(std::mem::size_of::<Point3<f32>>() == 12 && std::mem::align_of::<Point3<f32>>() == 4);

/// Selected correspondences as NumPy arrays: source index, target index, score.
type CorrespondenceArrays = (Py<PyArray1<u32>>, Py<PyArray1<u32>>, Py<PyArray1<f32>>);

/// The library's error as the Python package's exception (`cgenreg.errors`): the same
/// message, and for a file format error its path, field, expectation and finding.
fn to_py(e: cgenreg::Error) -> PyErr {
    match &e {
        // Python's own exceptions: an allocation refused before it was tried, and a call that
        // stopped at a Ctrl-C (see `interruptible`)
        cgenreg::Error::OutOfMemory { .. } => return PyMemoryError::new_err(e.to_string()),
        cgenreg::Error::Cancelled => return PyKeyboardInterrupt::new_err(e.to_string()),
        _ => {}
    }
    Python::attach(|py| {
        let build = || -> PyResult<PyErr> {
            let m = py.import("cgenreg.errors")?;
            let msg = e.to_string();
            let obj = match &e {
                cgenreg::Error::Format {
                    path,
                    field,
                    expected,
                    found,
                } => m.getattr("FormatError")?.call1((
                    msg,
                    path.display().to_string(),
                    field.as_str(),
                    expected.as_str(),
                    found.as_str(),
                ))?,
                cgenreg::Error::Io { path, source } => m.getattr("FileError")?.call1((
                    msg,
                    path.display().to_string(),
                    source.raw_os_error(),
                ))?,
                cgenreg::Error::Invalid(_)
                | cgenreg::Error::Shape(_)
                | cgenreg::Error::Param(_)
                | cgenreg::Error::Missing(_)
                | cgenreg::Error::Usage(_)
                | cgenreg::Error::Degenerate(_) => m.getattr("InvalidInput")?.call1((msg,))?,
                _ => m.getattr("CgenregError")?.call1((msg,))?,
            };
            Ok(PyErr::from_value(obj))
        };
        build().unwrap_or_else(|err| err)
    })
}

/// Runs `f` (the library's work, GIL released) on a worker thread while this thread checks for
/// signals every 50 ms: a Ctrl-C asks the library to stop ([`cgenreg::cancel`]), which it does
/// at its next step or loop check, and then raises `KeyboardInterrupt`. Without this a call ran
/// on the interpreter's thread with the GIL released and no signal checks, so Ctrl-C waited for
/// it to return.
fn interruptible<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> cgenreg::Result<T> + Send,
) -> PyResult<T> {
    use std::sync::mpsc::{channel, RecvTimeoutError};
    let (tx, rx) = channel();
    // shared with the GIL-released waits below, which need a `Sync` reference
    let rx = std::sync::Mutex::new(rx);
    std::thread::scope(|s| {
        // the caller's stack size: the library recursed on the interpreter's main thread before
        let worker = std::thread::Builder::new()
            .name("cgenreg".into())
            .stack_size(8 << 20)
            .spawn_scoped(s, move || {
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|p| {
                    cgenreg::Error::Panicked(cgenreg::error::panic_message(p.as_ref()))
                });
                let _ = tx.send(r.and_then(|r| r));
            })
            .map_err(|e| PyRuntimeError::new_err(format!("cannot start a thread: {e}")))?;
        loop {
            let got = py.detach(|| match rx.lock() {
                Ok(rx) => rx.recv_timeout(std::time::Duration::from_millis(50)),
                Err(_) => Err(RecvTimeoutError::Disconnected),
            });
            match got {
                Ok(r) => {
                    let _ = py.detach(move || worker.join());
                    return r.map_err(to_py);
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(PyRuntimeError::new_err(
                        "the computation ended without a result",
                    ))
                }
                Err(RecvTimeoutError::Timeout) => {}
            }
            if let Err(interrupt) = py.check_signals() {
                cgenreg::cancel::request();
                let _ = py.detach(move || worker.join());
                cgenreg::cancel::clear();
                return Err(interrupt);
            }
        }
    })
}

fn invalid(msg: String) -> PyErr {
    to_py(cgenreg::Error::Invalid(msg))
}

/// `a` as points, read in place (no copy): `a` must be (N, 3) and C-contiguous.
fn points_view<'a>(a: &'a PyReadonlyArray2<'_, f32>, what: &str) -> PyResult<&'a [Point3<f32>]> {
    let shape = a.shape();
    if shape[1] != 3 {
        return Err(invalid(format!(
            "{what}: expected an (N, 3) array of x, y, z, found shape ({}, {})",
            shape[0], shape[1]
        )));
    }
    let s = a
        .as_slice()
        .map_err(|_| invalid(format!("{what}: expected a C-contiguous array")))?;
    // SAFETY: `s` holds 3 * N f32 in row order; `Point3<f32>` has the layout of `[f32; 3]`
    // (asserted above); the slice lives as long as the borrowed array.
    Ok(unsafe { std::slice::from_raw_parts(s.as_ptr().cast::<Point3<f32>>(), s.len() / 3) })
}

/// An (N, D) float32 array as the library's row-major features (one copy into its type).
fn features(a: &PyReadonlyArray2<'_, f32>, what: &str) -> PyResult<Features> {
    let dim = a.shape()[1];
    if dim == 0 {
        return Err(invalid(format!(
            "{what}: expected at least one feature column"
        )));
    }
    let data = match a.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => a.as_array().iter().copied().collect(),
    };
    Ok(Features::new(dim, data))
}

/// Flat row-major values as an (n, cols) NumPy array that owns the Rust buffer (no copy).
fn rows<'py, T: numpy::Element>(
    py: Python<'py>,
    data: Vec<T>,
    cols: usize,
) -> PyResult<Bound<'py, PyArray2<T>>> {
    let n = data.len().checked_div(cols).unwrap_or(0);
    Array2::from_shape_vec((n, cols), data)
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

fn matrix4<'py>(py: Python<'py>, m: &[[f64; 4]; 4]) -> PyResult<Bound<'py, PyArray2<f64>>> {
    rows(py, m.iter().flatten().copied().collect(), 4)
}

fn flat_points(p: &[Point3<f32>]) -> Vec<f32> {
    p.iter().flat_map(|q| [q.x, q.y, q.z]).collect()
}

/// One registration's result. Arrays are made once, from the result's own buffers (moved,
/// not copied), and every access returns the same array.
#[pyclass(module = "cgenreg._cgenreg", name = "Result", frozen)]
struct RegResult {
    json: String,
    target_from_source: Py<PyArray2<f64>>,
    gt_target_from_source: Option<Py<PyArray2<f64>>>,
    corr_source: Py<PyArray1<u32>>,
    corr_target: Py<PyArray1<u32>>,
    corr_scores: Py<PyArray1<f32>>,
    inliers: Py<PyArray1<u64>>,
    source_keypoints: Py<PyArray2<f32>>,
    target_keypoints: Py<PyArray2<f32>>,
    rre_deg: Option<f64>,
    rte_m: Option<f64>,
    success: Option<bool>,
    inlier_ratio: Option<f64>,
    timings: Vec<(String, f64, String)>,
    total_ms: f64,
    pair_id: String,
    params_json: String,
    warnings: Vec<String>,
    estimator: String,
}

impl RegResult {
    fn new(py: Python<'_>, reg: Registered) -> PyResult<Self> {
        let r = reg.result;
        let json = serde_json::to_string(&r).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        let params_json = serde_json::to_string(&reg.params)
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        let (mut cs, mut ct, mut sc) = (
            Vec::with_capacity(r.correspondences.len()),
            Vec::with_capacity(r.correspondences.len()),
            Vec::with_capacity(r.correspondences.len()),
        );
        for c in &r.correspondences {
            cs.push(c.src);
            ct.push(c.tgt);
            sc.push(c.score);
        }
        let inliers: Vec<u64> = r.inliers.iter().map(|&i| i as u64).collect();
        Ok(RegResult {
            json,
            target_from_source: matrix4(py, &r.target_from_source)?.unbind(),
            gt_target_from_source: r
                .gt_target_from_source
                .as_ref()
                .map(|m| matrix4(py, m).map(Bound::unbind))
                .transpose()?,
            corr_source: Array1::from_vec(cs).into_pyarray(py).unbind(),
            corr_target: Array1::from_vec(ct).into_pyarray(py).unbind(),
            corr_scores: Array1::from_vec(sc).into_pyarray(py).unbind(),
            inliers: Array1::from_vec(inliers).into_pyarray(py).unbind(),
            source_keypoints: rows(py, flat_points(&r.source_keypoints), 3)?.unbind(),
            target_keypoints: rows(py, flat_points(&r.target_keypoints), 3)?.unbind(),
            rre_deg: r.metrics.as_ref().map(|m| m.rre_deg),
            rte_m: r.metrics.as_ref().map(|m| m.rte_m),
            success: r.metrics.as_ref().map(|m| m.success),
            inlier_ratio: r.metrics.as_ref().map(|m| m.inlier_ratio),
            timings: r
                .timings
                .iter()
                .map(|t| (t.stage.clone(), t.ms, t.status.clone()))
                .collect(),
            total_ms: r.total_ms,
            pair_id: r.pair_id.clone(),
            params_json,
            warnings: r.warnings.clone(),
            estimator: r.estimator.clone(),
        })
    }
}

#[pymethods]
impl RegResult {
    /// Estimated transform, (4, 4) float64: p_target = T @ p_source.
    #[getter]
    fn target_from_source(&self, py: Python<'_>) -> Py<PyArray2<f64>> {
        self.target_from_source.clone_ref(py)
    }
    /// The ground truth (4, 4) when it was given, else None.
    #[getter]
    fn gt_target_from_source(&self, py: Python<'_>) -> Option<Py<PyArray2<f64>>> {
        self.gt_target_from_source.as_ref().map(|a| a.clone_ref(py))
    }
    /// Selected correspondences: (source keypoint index uint32, target keypoint index
    /// uint32, score float32), sorted by score (highest first).
    #[getter]
    fn correspondences(&self, py: Python<'_>) -> CorrespondenceArrays {
        (
            self.corr_source.clone_ref(py),
            self.corr_target.clone_ref(py),
            self.corr_scores.clone_ref(py),
        )
    }
    /// Indices into `correspondences` that the estimator kept, uint64.
    #[getter]
    fn inliers(&self, py: Python<'_>) -> Py<PyArray1<u64>> {
        self.inliers.clone_ref(py)
    }
    /// The source keypoints (voxel-downsampled cloud), (N, 3) float32.
    #[getter]
    fn source_keypoints(&self, py: Python<'_>) -> Py<PyArray2<f32>> {
        self.source_keypoints.clone_ref(py)
    }
    /// The target keypoints, (M, 3) float32.
    #[getter]
    fn target_keypoints(&self, py: Python<'_>) -> Py<PyArray2<f32>> {
        self.target_keypoints.clone_ref(py)
    }
    /// Relative rotation error (degrees) against the ground truth; None without one.
    #[getter]
    fn rre_deg(&self) -> Option<f64> {
        self.rre_deg
    }
    /// Relative translation error (metres) against the ground truth; None without one.
    #[getter]
    fn rte_m(&self) -> Option<f64> {
        self.rte_m
    }
    /// RRE <= 15 deg and RTE <= 0.30 m; None without ground truth.
    #[getter]
    fn success(&self) -> Option<bool> {
        self.success
    }
    /// Fraction of the selected correspondences within the inlier threshold under the ground
    /// truth; None without one.
    #[getter]
    fn inlier_ratio(&self) -> Option<f64> {
        self.inlier_ratio
    }
    /// Stage timings as (stage, milliseconds, "computed" | "cached").
    #[getter]
    fn timings(&self) -> Vec<(String, f64, String)> {
        self.timings.clone()
    }
    /// Wall time of the whole registration (ms), loading included.
    #[getter]
    fn total_ms(&self) -> f64 {
        self.total_ms
    }
    #[getter]
    fn pair_id(&self) -> String {
        self.pair_id.clone()
    }
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }
    /// Which estimator produced the pose ("sc2pcr", "weighted-svd (fallback)", ...).
    #[getter]
    fn estimator(&self) -> String {
        self.estimator.clone()
    }
    /// The result as `cgenreg register --json` prints it (a JSON string).
    fn to_json(&self) -> String {
        self.json.clone()
    }
    /// The settings the registration ran with (the pipeline's `RegisterParams`, JSON string).
    fn params_json(&self) -> String {
        self.params_json.clone()
    }
    fn __repr__(&self) -> String {
        match (self.rre_deg, self.rte_m) {
            (Some(r), Some(t)) => format!(
                "<cgenreg.Result {}: RRE {r:.3} deg, RTE {t:.3} m, {} correspondences>",
                self.pair_id,
                self.corr_count()
            ),
            _ => format!(
                "<cgenreg.Result {}: {} correspondences, no ground truth>",
                self.pair_id,
                self.corr_count()
            ),
        }
    }
}

impl RegResult {
    fn corr_count(&self) -> usize {
        Python::attach(|py| self.corr_scores.bind(py).len())
    }
}

/// The pipeline's settings for these `cgenreg register` options, as JSON.
#[pyfunction]
fn settings(py: Python<'_>, options: Vec<String>) -> PyResult<String> {
    let p = interruptible(py, || cgenreg::cli::register_settings(&options))?;
    serde_json::to_string(&p).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

type CloudArrays<'py> = (
    Bound<'py, PyArray2<f64>>,
    Option<Bound<'py, PyArray1<f32>>>,
    Option<Bound<'py, PyArray2<u8>>>,
    Option<Bound<'py, PyArray2<f32>>>,
);

/// A cloud file by the CLI's readers: points (N, 3) float64, intensity, colours, normals.
#[pyfunction]
fn read_cloud(py: Python<'_>, path: PathBuf) -> PyResult<CloudArrays<'_>> {
    let c = interruptible(py, || cgenreg::io::cloud::load_cloud(&path))?;
    let pts: Vec<f64> = c
        .points
        .iter()
        .flat_map(|p| [p.x as f64, p.y as f64, p.z as f64])
        .collect();
    let colors = c
        .colors
        .map(|v| rows(py, v.into_iter().flatten().collect(), 3))
        .transpose()?;
    let normals = c
        .normals
        .map(|v| rows(py, v.iter().flat_map(|n| [n.x, n.y, n.z]).collect(), 3))
        .transpose()?;
    Ok((
        rows(py, pts, 3)?,
        c.intensity.map(|v| Array1::from_vec(v).into_pyarray(py)),
        colors,
        normals,
    ))
}

/// Writes points by the library's writers (.ply, .npy, .xyz/.txt/.pts), through the command
/// line's output guard (`force` replaces a file cgenreg did not write).
#[pyfunction]
#[pyo3(signature = (path, points, intensity=None, force=false))]
fn write_cloud(
    py: Python<'_>,
    path: PathBuf,
    points: PyReadonlyArray2<'_, f32>,
    intensity: Option<PyReadonlyArray1<'_, f32>>,
    force: bool,
) -> PyResult<()> {
    let cloud = cloud_from(&points, intensity.as_ref(), "points")?;
    interruptible(py, || {
        cgenreg::io::cloud::save_cloud_guarded(&path, &cloud, force)
    })
}

fn cloud_from(
    points: &PyReadonlyArray2<'_, f32>,
    intensity: Option<&PyReadonlyArray1<'_, f32>>,
    what: &str,
) -> PyResult<PointCloud> {
    let view = points_view(points, what)?;
    // the registration's own copies of the points, estimated before any is made: an
    // allocation that fails would abort the interpreter
    cgenreg::io::limits::check_memory(
        &format!("{what}: {} points", view.len()),
        (view.len() as u64).saturating_mul(cgenreg::io::limits::BYTES_PER_INPUT_POINT),
    )
    .map_err(to_py)?;
    let mut copy =
        cgenreg::io::limits::try_vec(&format!("{what}: a copy of the points"), view.len())
            .map_err(to_py)?;
    copy.extend_from_slice(view);
    let mut c = PointCloud::from_points(copy);
    if let Some(i) = intensity {
        let v = i.as_array().to_vec();
        if v.len() != c.len() {
            return Err(invalid(format!(
                "{what} intensity: expected {} values (one per point), found {}",
                c.len(),
                v.len()
            )));
        }
        c.intensity = Some(v);
    }
    if let Some(i) = c
        .points
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()))
    {
        return Err(invalid(format!(
            "{what}: point {i}: expected finite x, y, z, found ({}, {}, {})",
            c.points[i].x, c.points[i].y, c.points[i].z
        )));
    }
    Ok(c)
}

fn run_registration(py: Python<'_>, input: PairInput, options: Vec<String>) -> PyResult<RegResult> {
    let reg = interruptible(py, || cgenreg::cli::register_with_options(input, &options))?;
    RegResult::new(py, reg)
}

/// `cgenreg register --source --target [--gt]` on files.
#[pyfunction]
#[pyo3(signature = (source, target, gt, options))]
fn register_files(
    py: Python<'_>,
    source: PathBuf,
    target: PathBuf,
    gt: Option<PathBuf>,
    options: Vec<String>,
) -> PyResult<RegResult> {
    run_registration(py, PairInput::Files { source, target, gt }, options)
}

/// `cgenreg register --manifest --pair`.
#[pyfunction]
fn register_pair(
    py: Python<'_>,
    manifest: PathBuf,
    pair: String,
    options: Vec<String>,
) -> PyResult<RegResult> {
    run_registration(py, PairInput::Manifest { manifest, pair }, options)
}

/// A registration of two point arrays (float32, (N, 3)); `gt` a (4, 4) target_from_source.
#[pyfunction]
#[pyo3(signature = (source, target, gt, options, source_intensity=None, target_intensity=None))]
fn register_arrays(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f32>,
    target: PyReadonlyArray2<'_, f32>,
    gt: Option<PyReadonlyArray2<'_, f64>>,
    options: Vec<String>,
    source_intensity: Option<PyReadonlyArray1<'_, f32>>,
    target_intensity: Option<PyReadonlyArray1<'_, f32>>,
) -> PyResult<RegResult> {
    let t0 = std::time::Instant::now();
    let scan = |name: &str, c: PointCloud| -> PyResult<Scan> {
        Ok(Scan {
            name: name.into(),
            cloud: c,
            frames: None,
            notes: Vec::new(),
        })
    };
    let s = scan(
        "source",
        cloud_from(&source, source_intensity.as_ref(), "source")?,
    )?;
    let t = scan(
        "target",
        cloud_from(&target, target_intensity.as_ref(), "target")?,
    )?;
    let gt = match gt {
        None => None,
        Some(g) => {
            let a = g.as_array();
            if a.shape() != [4, 4] {
                return Err(invalid(format!(
                    "gt: expected a (4, 4) target_from_source matrix, found shape {:?}",
                    a.shape()
                )));
            }
            let m = nalgebra::Matrix4::from_fn(|r, c| a[[r, c]]);
            Some(
                cgenreg::geometry::transform::isometry_from_matrix(&m).ok_or_else(|| {
                    invalid(
                        "gt: expected a finite rigid 4x4 transform (last row 0 0 0 1), found a \
                         non-rigid matrix"
                            .into(),
                    )
                })?,
            )
        }
    };
    let pair = ScanPair {
        id: "arrays/target-source".into(),
        source: s,
        target: t,
        gt_target_from_source: gt,
    };
    let load_ms = t0.elapsed().as_secs_f64() * 1e3;
    run_registration(
        py,
        PairInput::Loaded {
            pair: Box::new(pair),
            load_ms,
        },
        options,
    )
}

/// The pipeline's geometric branch of one cloud: keypoints (K, 3) and FPFH (K, 33), float32.
#[allow(clippy::type_complexity)]
#[pyfunction]
fn fpfh<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f32>,
    voxel: f64,
) -> PyResult<(Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<f32>>)> {
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(invalid(format!(
            "voxel: expected a positive length in metres, found {voxel}"
        )));
    }
    let cloud = cloud_from(&points, None, "points")?;
    let b = interruptible(py, || cgenreg::pipeline::geo::fpfh_branch(&cloud, voxel))?;
    let dim = b.features.dim;
    Ok((
        rows(py, flat_points(&b.keypoints.points), 3)?,
        rows(py, b.features.data, dim)?,
    ))
}

type Corr<'py> = (
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<f32>>,
);

/// Similarity, calibration, Match-then-Fuse and selection, as the pipeline runs them.
#[pyfunction]
#[pyo3(signature = (source_geo, target_geo, options, source_img=None, source_valid=None, target_img=None, target_valid=None))]
#[allow(clippy::too_many_arguments)]
fn match_then_fuse<'py>(
    py: Python<'py>,
    source_geo: PyReadonlyArray2<'py, f32>,
    target_geo: PyReadonlyArray2<'py, f32>,
    options: Vec<String>,
    source_img: Option<PyReadonlyArray2<'py, f32>>,
    source_valid: Option<PyReadonlyArray1<'py, bool>>,
    target_img: Option<PyReadonlyArray2<'py, f32>>,
    target_valid: Option<PyReadonlyArray1<'py, bool>>,
) -> PyResult<Corr<'py>> {
    use cgenreg::fusion::{
        cosine_similarity, match_then_fuse_select, Calibration, FusionMode, Selection,
    };
    let fs = features(&source_geo, "source_geo")?;
    let ft = features(&target_geo, "target_geo")?;
    let image = match (&source_img, &target_img) {
        (Some(a), Some(b)) => {
            let (ia, ib) = (features(a, "source_img")?, features(b, "target_img")?);
            let valid = |v: &Option<PyReadonlyArray1<'py, bool>>, n: usize| match v {
                Some(v) => v.as_array().to_vec(),
                None => vec![true; n],
            };
            let (va, vb) = (
                valid(&source_valid, ia.len()),
                valid(&target_valid, ib.len()),
            );
            Some((ia, va, ib, vb))
        }
        (None, None) => None,
        _ => {
            return Err(invalid(
                "match_then_fuse: give both source_img and target_img, or neither".into(),
            ))
        }
    };
    let mut params = cgenreg::cli::fusion_settings(&options, image.is_some()).map_err(to_py)?;
    if image.is_none() {
        params.fusion.mode = FusionMode::GeometryOnly;
    }
    let corr = interruptible(py, || -> cgenreg::Result<_> {
        match &image {
            Some((ia, va, ib, vb)) => {
                // the paper's configuration streams from the features (same
                // correspondences, no N x M matrix); others form the matrices within the
                // dense-matrix budget
                let streamed = cgenreg::fusion::match_then_fuse_select_features(
                    (ia, va.as_slice(), ib, vb.as_slice()),
                    (&fs, &ft),
                    &params.fusion,
                )?;
                if let Some(c) = streamed {
                    return Ok(c);
                }
                let geo = cosine_similarity(&fs, &ft)?;
                let img = cosine_similarity(ia, ib)?;
                match_then_fuse_select(Some((&img, Some(va), Some(vb))), Some(&geo), &params.fusion)
            }
            None => match (params.fusion.selection, params.fusion.calibration_geo) {
                // as the pipeline's geometric-only tail: row softmax keeps each row's
                // argmax, so row NN needs no N x M matrix (same correspondences)
                (Selection::RowNn, Calibration::RowSoftmax { tau }) => {
                    cgenreg::fusion::streaming::row_nn_posterior(&fs, &ft, tau)
                }
                _ => match_then_fuse_select(
                    None,
                    Some(&cosine_similarity(&fs, &ft)?),
                    &params.fusion,
                ),
            },
        }
    })?;
    let (mut a, mut b, mut s) = (Vec::new(), Vec::new(), Vec::new());
    for c in corr {
        a.push(c.src);
        b.push(c.tgt);
        s.push(c.score);
    }
    Ok((
        Array1::from_vec(a).into_pyarray(py),
        Array1::from_vec(b).into_pyarray(py),
        Array1::from_vec(s).into_pyarray(py),
    ))
}

type EstimateOut<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<u64>>,
    String,
    Option<String>,
);

/// The pipeline's estimator on correspondence endpoints `src[i] <-> tgt[i]` (read in place).
#[pyfunction]
#[pyo3(signature = (src, tgt, scores, options))]
fn estimate<'py>(
    py: Python<'py>,
    src: PyReadonlyArray2<'py, f32>,
    tgt: PyReadonlyArray2<'py, f32>,
    scores: Option<PyReadonlyArray1<'py, f32>>,
    options: Vec<String>,
) -> PyResult<EstimateOut<'py>> {
    let (s, t) = (points_view(&src, "src_xyz")?, points_view(&tgt, "tgt_xyz")?);
    if s.len() != t.len() {
        return Err(invalid(format!(
            "src_xyz has {} points but tgt_xyz has {}: expected one target point per source point",
            s.len(),
            t.len()
        )));
    }
    let w: Vec<f32> = match &scores {
        Some(w) => w.as_array().to_vec(),
        None => vec![1.0; s.len()],
    };
    let params = cgenreg::cli::fusion_settings(&options, false).map_err(to_py)?;
    let e = interruptible(py, || {
        cgenreg::estimate::estimate_pose(s, t, &w, &params.estimator)
    })?;
    let m = cgenreg::pipeline::result::matrix_rows(&e.target_from_source);
    let inl: Vec<u64> = e.inliers.iter().map(|&i| i as u64).collect();
    Ok((
        matrix4(py, &m)?,
        Array1::from_vec(inl).into_pyarray(py),
        e.method,
        e.warning,
    ))
}

/// A `cgenreg bench --json` (or `merge`) output, checked by the library's reader, as JSON:
/// label, params, identity, manifest and the per-pair rows.
#[pyfunction]
fn load_bench(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    let run = interruptible(py, || cgenreg::report::compare::load_bench_run(&path))?;
    let v = serde_json::json!({
        "label": run.label,
        "params": run.params,
        "identity": run.identity,
        "manifest": run.manifest,
        "pairs": run.pairs,
    });
    Ok(v.to_string())
}

/// The pairs of a dataset manifest: (id, split, source, target, gt target_from_source or None).
#[allow(clippy::type_complexity)]
#[pyfunction]
fn manifest_pairs<'py>(
    py: Python<'py>,
    manifest: PathBuf,
) -> PyResult<
    Vec<(
        String,
        String,
        String,
        String,
        Option<Bound<'py, PyArray2<f64>>>,
    )>,
> {
    let ds = interruptible(py, || cgenreg::dataset::Dataset::load(&manifest))?;
    ds.pairs()
        .iter()
        .map(|p| {
            let gt = p
                .gt_target_from_source
                .as_ref()
                .map(|g| matrix4(py, &cgenreg::pipeline::result::matrix_rows(g)))
                .transpose()?;
            Ok((
                p.id.clone(),
                p.split.clone(),
                p.source.clone(),
                p.target.clone(),
                gt,
            ))
        })
        .collect()
}

/// The command line in-process (`argv[0]` is the program name); returns the exit code.
#[pyfunction]
fn cli_main(py: Python<'_>, argv: Vec<String>) -> PyResult<i32> {
    let argv = argv.into_iter().map(Into::into).collect();
    interruptible(py, || Ok(cgenreg::cli::main_with_args(argv)))
}

#[pymodule]
fn _cgenreg(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<RegResult>()?;
    m.add_function(wrap_pyfunction!(settings, m)?)?;
    m.add_function(wrap_pyfunction!(read_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(write_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(register_files, m)?)?;
    m.add_function(wrap_pyfunction!(register_pair, m)?)?;
    m.add_function(wrap_pyfunction!(register_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(fpfh, m)?)?;
    m.add_function(wrap_pyfunction!(match_then_fuse, m)?)?;
    m.add_function(wrap_pyfunction!(estimate, m)?)?;
    m.add_function(wrap_pyfunction!(load_bench, m)?)?;
    m.add_function(wrap_pyfunction!(cli_main, m)?)?;
    m.add_function(wrap_pyfunction!(manifest_pairs, m)?)?;
    m.add("HAS_GUI", cfg!(feature = "gui"))?;
    m.add("VERSION", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
