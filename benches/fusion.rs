//! Match-then-Fuse benchmark: calibration + fusion + selection at N = M = 5,000 and 20,000,
//! and cosine similarity at 5k x 5k for D = 33 (FPFH) and D = 256 (GeoTransformer).
//! Run: `cargo bench --no-default-features --bench fusion` (N_LARGE=0 skips the 20k case).
//! Prints a markdown table: median wall time over the runs, and the peak heap growth measured
//! by a counting global allocator (inputs excluded).

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use cgenreg::features::Features;
use cgenreg::fusion::fuse::noisy_and_rank_keys;
use cgenreg::fusion::{
    calibrate, calibrate_in_place, cosine_similarity, fuse, match_then_fuse,
    match_then_fuse_select, select, Calibration, DenseMatrix, FusionMode, FusionParams, Selection,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

struct Counting;
static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(l) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) };
        CURRENT.fetch_sub(l.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        let q = unsafe { System.realloc(p, l, new) };
        if !q.is_null() {
            if new > l.size() {
                let now = CURRENT.fetch_add(new - l.size(), Ordering::Relaxed) + new - l.size();
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                CURRENT.fetch_sub(l.size() - new, Ordering::Relaxed);
            }
        }
        q
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Cosine-like similarities in [-1, 1] with a planted permutation raised above the noise.
fn planted(n: usize, seed: u64, signal: f32) -> (DenseMatrix, Vec<usize>) {
    let mut r = Rng(seed);
    let perm: Vec<usize> = (0..n).map(|i| (i * 7919 + 13) % n).collect();
    let mut data = vec![0.0f32; n * n];
    for (i, row) in data.chunks_mut(n).enumerate() {
        for v in row.iter_mut() {
            *v = 0.6 * (r.uniform() + r.uniform() - 1.0);
        }
        row[perm[i]] = (row[perm[i]] + signal).min(1.0);
    }
    (DenseMatrix::from_vec(n, n, data).unwrap(), perm)
}

/// CPU seconds (user + system, all threads) of this process so far, from /proc/self/stat.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |k: usize| f.get(k).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Median seconds and peak extra heap bytes of `f` over `runs` runs.
fn measure<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, usize, T) {
    let mut times = vec![];
    let mut peak = 0;
    let mut last = None;
    let c0 = cpu_seconds();
    for _ in 0..runs {
        drop(last.take());
        let base = CURRENT.load(Ordering::Relaxed);
        PEAK.store(base, Ordering::Relaxed);
        let t = Instant::now();
        let out = f();
        times.push(t.elapsed().as_secs_f64());
        peak = peak.max(PEAK.load(Ordering::Relaxed) - base);
        last = Some(out);
    }
    let cpu = (cpu_seconds() - c0) / runs as f64;
    LAST_CPU_MS.store((cpu * 1e3) as usize, Ordering::Relaxed);
    (median(times), peak, last.unwrap())
}

/// Mean CPU milliseconds per run of the last `measure` (10 ms tick resolution, all threads).
static LAST_CPU_MS: AtomicUsize = AtomicUsize::new(0);

fn cpu_ms() -> usize {
    LAST_CPU_MS.load(Ordering::Relaxed)
}

fn mib(b: usize) -> f64 {
    b as f64 / (1024.0 * 1024.0)
}

fn main() {
    let large: usize = std::env::var("N_LARGE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000);
    // Optional filter: `cargo bench --bench fusion -- paper` runs only the configurations whose
    // name contains an argument ("stages" and "cosine" select those tables).
    let filter: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let wanted = |name: &str| filter.is_empty() || filter.iter().any(|f| name.contains(f.as_str()));
    println!("threads: {}\n", rayon::current_num_threads());
    println!("| N = M | configuration | wall ms (median) | CPU ms / run | peak extra heap (MiB) | N x M f32 (MiB) | correct / found |");
    println!("|---|---|---|---|---|---|---|");
    let configs: Vec<(&str, FusionParams)> = vec![
        (
            "paper: row softmax + Noisy-AND + mutual NN",
            FusionParams::default(),
        ),
        (
            "reference: dual softmax + f32 Noisy-AND + top-8000",
            FusionParams::reference(),
        ),
        (
            "row softmax + Noisy-OR + mutual NN",
            FusionParams {
                mode: FusionMode::NoisyOr,
                ..FusionParams::default()
            },
        ),
        (
            "dual softmax + Noisy-AND (stable) + mutual NN",
            FusionParams {
                calibration_img: Calibration::DualSoftmax { tau: 0.1 },
                calibration_geo: Calibration::DualSoftmax { tau: 0.1 },
                selection: Selection::MutualNn,
                ..FusionParams::default()
            },
        ),
    ];
    for &n in [5_000usize, large].iter().filter(|&&n| n > 0) {
        let (s_img, perm) = planted(n, 1, 0.5);
        let (s_geo, _) = planted(n, 2, 0.5);
        let runs = if n <= 5_000 { 7 } else { 3 };
        for (name, p) in &configs {
            if n > 5_000 && !name.starts_with("paper") && !name.starts_with("reference")
                || !wanted(name)
            {
                continue;
            }
            let (t, peak, out) = measure(runs, || {
                match_then_fuse(Some((&s_img, None, None)), Some(&s_geo), p).unwrap()
            });
            let ok = out
                .correspondences
                .iter()
                .filter(|c| perm[c.src as usize] == c.tgt as usize)
                .count();
            println!(
                "| {n} | {name} | {:.1} | {} | {:.0} | {:.0} | {ok} / {} |",
                t * 1e3,
                cpu_ms(),
                mib(peak),
                mib(n * n * 4),
                out.correspondences.len()
            );
        }
        let name = "paper, correspondences only (match_then_fuse_select: no N x M matrix)";
        if wanted(name) {
            let p = FusionParams::default();
            let (t, peak, corr) = measure(runs, || {
                match_then_fuse_select(Some((&s_img, None, None)), Some(&s_geo), &p).unwrap()
            });
            let ok = corr
                .iter()
                .filter(|c| perm[c.src as usize] == c.tgt as usize)
                .count();
            println!(
                "| {n} | {name} | {:.1} | {} | {:.0} | {:.0} | {ok} / {} |",
                t * 1e3,
                cpu_ms(),
                mib(peak),
                mib(n * n * 4),
                corr.len()
            );
        }
    }

    // Stage breakdown at 5k (one branch calibrated; fusion and selection on the results).
    if wanted("stages") {
        let n = 5_000;
        let (s_img, _) = planted(n, 1, 0.5);
        let (s_geo, _) = planted(n, 2, 0.5);
        println!(
            "\n| stage at 5000 x 5000 | wall ms (median) | CPU ms / run | peak extra heap (MiB) |"
        );
        println!("|---|---|---|---|");
        let stage = |name: &str, t: f64, peak: usize| {
            println!(
                "| {name} | {:.1} | {} | {:.0} |",
                t * 1e3,
                cpu_ms(),
                mib(peak)
            );
        };
        let row = Calibration::RowSoftmax { tau: 0.1 };
        let dual = Calibration::DualSoftmax { tau: 0.1 };
        let mut buf = s_img.clone();
        let (t, p, _) = measure(7, || buf.data.copy_from_slice(&s_img.data));
        stage(
            "copy 100 MB into an existing matrix (reference point)",
            t,
            p,
        );
        let (t, p, _) = measure(7, || s_img.clone());
        stage(
            "clone one N x M matrix (fresh pages; reference point)",
            t,
            p,
        );
        let (t, p, _) = measure(7, || s_img.duplicate().unwrap());
        stage("duplicate one N x M matrix (huge pages)", t, p);
        let (t, p, _) = measure(7, || calibrate(&s_img, None, None, row).unwrap());
        stage("row softmax into a new matrix", t, p);
        let (t, p, _) = measure(7, || calibrate_in_place(&mut buf, None, None, row).unwrap());
        stage("row softmax, in place", t, p);
        let (t, p, _) = measure(7, || {
            buf.data.copy_from_slice(&s_img.data);
            calibrate_in_place(&mut buf, None, None, dual).unwrap()
        });
        stage("dual softmax, in place (incl. copy-in)", t, p);
        let p_img = calibrate(&s_img, None, None, row).unwrap();
        let p_geo = calibrate(&s_geo, None, None, row).unwrap();
        let (t, p, _) = measure(7, || {
            fuse(
                Some(&p_img),
                Some(&p_geo),
                FusionMode::NoisyAnd,
                None,
                false,
            )
            .unwrap()
        });
        stage("Noisy-AND posteriors (new matrix)", t, p);
        let (t, p, keys) = measure(7, || noisy_and_rank_keys(&p_img, &p_geo).unwrap());
        stage("Noisy-AND rank keys (new matrix)", t, p);
        let (t, p, _) = measure(7, || select(&keys, Selection::MutualNn));
        stage("mutual NN", t, p);
        let (t, p, _) = measure(7, || select(&keys, Selection::TopK(8000)));
        stage("top-8000", t, p);
    }

    if wanted("cosine") {
        cosine_table();
    }
    if wanted("rownn") {
        row_nn_table();
    }
    if let Ok(l) = std::fs::read_to_string("/proc/loadavg") {
        println!("\nload average after the run: {}", l.trim());
    }
}

fn cosine_table() {
    println!("\n| cosine similarity | wall ms (median) | CPU ms / run | peak extra heap (MiB) |");
    println!("|---|---|---|---|");
    for d in [33usize, 256] {
        let n = 5_000;
        let mut r = Rng(d as u64);
        let a = Features::new(d, (0..n * d).map(|_| r.uniform() - 0.5).collect());
        let b = Features::new(d, (0..n * d).map(|_| r.uniform() - 0.5).collect());
        let (t, peak, s) = measure(5, || cosine_similarity(&a, &b).unwrap());
        assert_eq!(s.shape(), (n, n));
        let gflops = 2.0 * (n * n * d) as f64 / t / 1e9;
        println!(
            "| 5000 x 5000, D = {d} | {:.1} ({gflops:.1} GFLOP/s) | {} | {:.0} |",
            t * 1e3,
            cpu_ms(),
            mib(peak)
        );
    }
}

/// The inspector's geometry-only re-fusion: each row's best target and its row-softmax
/// probability from a kept similarity matrix.
fn row_nn_table() {
    println!("\n| row NN + softmax from a kept similarity | wall ms (median) | CPU ms / run |");
    println!("|---|---|---|");
    for n in [5_000usize, 7_000] {
        let (s, _) = planted(n, 7, 0.3);
        let (t, _, c) = measure(7, || {
            cgenreg::fusion::streaming::row_nn_from_similarity(&s, 0.1).unwrap()
        });
        assert_eq!(c.len(), n);
        println!("| {n} x {n} | {:.1} | {} |", t * 1e3, cpu_ms());
    }
}
