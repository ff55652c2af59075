//! SC2-PCR's compatibility graph: the `hard`, `tight` and `near` bitsets, SC as sparse upper
//! rows, the SC matvec and leading eigenvector, NMS seeds and the SC2 top-k.

use super::soa::Soa;
use super::{allclose, normalise};
use crate::simd::Isa;
use rayon::prelude::*;

/// The compatibility graph: `hard`, `tight` and `near` bitsets (n rows of `stride` u64 each,
/// so that the tight rows scanned by SC2 are contiguous) and SC values.
pub(crate) struct Graph {
    pub n: usize,
    /// u64 words per bitset row: ceil(n / 64) rounded up to a multiple of 8, zero-padded.
    stride: usize,
    hard: Vec<u64>,
    tight: Vec<u64>,
    near: Vec<u64>,
    /// The upper triangle of SC in compressed rows: row i holds (column j > i, SC value) for
    /// every set bit of `hard[i]` with j > i, ascending.
    sc_start: Vec<usize>,
    sc_col: Vec<u32>,
    sc_val: Vec<f32>,
    /// Row ranges of the matvec's fixed partition (fixed so the f32 sums are deterministic).
    parts: Vec<(usize, usize)>,
    isa: Isa,
    /// `|tight[i]|`, an upper bound of every SC2 value in row or column i.
    tight_count: Vec<u32>,
    /// Rows with `|tight[i]| > 0` by decreasing `|tight[i]|`, ties by index.
    by_tight: Vec<u32>,
}

/// In-place transpose of a 64 x 64 bit matrix: bit c of `a[r]` becomes bit r of `a[c]`.
pub(super) fn transpose64(a: &mut [u64; 64]) {
    let mut j = 32usize;
    let mut m: u64 = 0x0000_0000_FFFF_FFFF;
    while j != 0 {
        let mut k = 0usize;
        while k < 64 {
            // Swap the high j bits of a[k] with the low j bits of a[k + j], per j-block.
            let t = ((a[k] >> j) ^ a[k | j]) & m;
            a[k] ^= t << j;
            a[k | j] ^= t;
            k = ((k | j) + 1) & !j;
        }
        j >>= 1;
        m ^= m << j;
    }
}

/// A raw pointer that may cross threads; every use documents why its accesses are disjoint.
#[derive(Clone, Copy)]
struct SharedMut(*mut u64);
// SAFETY: only used for disjoint writes/reads described at the use site.
unsafe impl Send for SharedMut {}
unsafe impl Sync for SharedMut {}

/// Indices of the set bits of a row, ascending.
#[inline]
fn for_each_bit(row: &[u64], mut f: impl FnMut(usize)) {
    for (w, &word) in row.iter().enumerate() {
        let mut m = word;
        while m != 0 {
            f(w * 64 + m.trailing_zeros() as usize);
            m &= m - 1;
        }
    }
}

#[inline]
pub(super) fn bit(row: &[u64], j: usize) -> bool {
    row[j / 64] >> (j % 64) & 1 == 1
}

impl Graph {
    pub fn build(p: &Soa, d: f32, nms: f32) -> Graph {
        let n = p.n;
        let words = n.div_ceil(64);
        // Rows padded to whole 512-bit vectors (the padding stays 0).
        let stride = words.div_ceil(8) * 8;
        let mut hard = vec![0u64; n * stride];
        let mut tight = vec![0u64; n * stride];
        let mut near = vec![0u64; n * stride];
        let isa = crate::simd::features().bitset_isa();
        let cols = p.columns();
        // Pass 1: the diagonal 64-column block and everything right of it (all three relations
        // are symmetric: `cross(i, j)` and `cross(j, i)` are bit-identical).
        let rows: Vec<Vec<(u32, f32)>> = hard
            .par_chunks_mut(stride)
            .zip(tight.par_chunks_mut(stride))
            .zip(near.par_chunks_mut(stride))
            .enumerate()
            .map(|(i, ((h, t), r))| {
                let row = (h, t, r);
                let w0 = i / 64;
                let mut vals = Vec::with_capacity((n - i) / 8 + 16);
                crate::simd::compat_row(isa, cols, i, d, nms, w0, words, row, &mut vals);
                vals
            })
            .collect();
        // Pass 2: the words left of the diagonal block, as 64 x 64 bit transposes of pass 1's.
        let blocks = words;
        let ptrs = [
            SharedMut(hard.as_mut_ptr()),
            SharedMut(tight.as_mut_ptr()),
            SharedMut(near.as_mut_ptr()),
        ];
        (1..blocks).into_par_iter().for_each(|bi| {
            let rows_i = (n - bi * 64).min(64);
            let mut tile = [0u64; 64];
            for ptr in ptrs {
                for bj in 0..bi {
                    // Block bj < bi is full (64 rows). Reads: word bi of rows in block bj,
                    // written by pass 1 only. Writes: word bj < bi of rows in block bi, which
                    // only this task touches and no task reads.
                    for (a, t) in tile.iter_mut().enumerate() {
                        // SAFETY: (bj * 64 + a) < n and bi < words: in bounds; see above.
                        *t = unsafe { *ptr.0.add((bj * 64 + a) * stride + bi) };
                    }
                    transpose64(&mut tile);
                    for (b, &t) in tile.iter().enumerate().take(rows_i) {
                        // SAFETY: (bi * 64 + b) < n and bj < words: in bounds; see above.
                        unsafe { *ptr.0.add((bi * 64 + b) * stride + bj) = t };
                    }
                }
            }
        });
        let tight_count: Vec<u32> = tight
            .chunks(stride)
            .map(|r| r.iter().map(|w| w.count_ones()).sum())
            .collect();
        let mut by_tight: Vec<u32> = (0..n as u32)
            .filter(|&j| tight_count[j as usize] > 0)
            .collect();
        by_tight.sort_unstable_by(|&a, &b| {
            tight_count[b as usize]
                .cmp(&tight_count[a as usize])
                .then(a.cmp(&b))
        });
        let mut sc_start = Vec::with_capacity(n + 1);
        sc_start.push(0);
        for r in &rows {
            sc_start.push(sc_start[sc_start.len() - 1] + r.len());
        }
        let nnz = sc_start[n];
        let mut sc_col = Vec::with_capacity(nnz);
        let mut sc_val = Vec::with_capacity(nnz);
        for r in rows {
            for (j, v) in r {
                sc_col.push(j);
                sc_val.push(v);
            }
        }
        // About equal work per part: each entry is read once (gather) and written once
        // (scatter), each row also costs a little.
        const PARTS: usize = 16;
        let cost = |i: usize| sc_start[i] + 8 * i;
        let total = cost(n);
        let mut parts = Vec::with_capacity(PARTS);
        let mut lo = 0;
        for k in 1..=PARTS {
            let want = total * k / PARTS;
            let mut hi = lo;
            while hi < n && cost(hi) < want {
                hi += 1;
            }
            if k == PARTS {
                hi = n;
            }
            if hi > lo {
                parts.push((lo, hi));
            }
            lo = hi;
        }
        Graph {
            n,
            stride,
            hard,
            tight,
            near,
            sc_start,
            sc_col,
            sc_val,
            parts,
            isa,
            tight_count,
            by_tight,
        }
    }

    pub fn hard(&self, i: usize) -> &[u64] {
        &self.hard[i * self.stride..(i + 1) * self.stride]
    }
    pub fn tight(&self, i: usize) -> &[u64] {
        &self.tight[i * self.stride..(i + 1) * self.stride]
    }
    pub fn near(&self, i: usize) -> &[u64] {
        &self.near[i * self.stride..(i + 1) * self.stride]
    }

    /// `y = SC x`, from the upper triangle: each part of rows gathers `SC[i, j>i] x_j` and
    /// scatters `SC[i, j] x_i` into its own buffer; buffers are summed in a fixed order.
    fn matvec(&self, x: &[f32], y: &mut [f32]) {
        let n = self.n;
        let partial: Vec<Vec<f32>> = self
            .parts
            .par_iter()
            .map(|&(lo, hi)| {
                let mut yl = vec![0f32; n];
                for i in lo..hi {
                    let r = self.sc_start[i]..self.sc_start[i + 1];
                    let (cols, vals) = (&self.sc_col[r.clone()], &self.sc_val[r]);
                    let xi = x[i];
                    let mut acc = [0f32; 4];
                    let (cc, vc) = (cols.chunks_exact(4), vals.chunks_exact(4));
                    let (cr, vr) = (cc.remainder(), vc.remainder());
                    for (c, v) in cc.zip(vc) {
                        for l in 0..4 {
                            let j = c[l] as usize;
                            acc[l] += v[l] * x[j];
                            yl[j] += v[l] * xi;
                        }
                    }
                    for (&j, &v) in cr.iter().zip(vr) {
                        acc[0] += v * x[j as usize];
                        yl[j as usize] += v * xi;
                    }
                    yl[i] += (acc[0] + acc[1]) + (acc[2] + acc[3]);
                }
                yl
            })
            .collect();
        y.par_chunks_mut(1024).enumerate().for_each(|(c, ys)| {
            let base = c * 1024;
            for (k, yv) in ys.iter_mut().enumerate() {
                *yv = partial.iter().map(|p| p[base + k]).sum();
            }
        });
    }

    /// Leading eigenvector of SC by power iteration from ones (reference
    /// `cal_leading_eigenvector`: normalise by ‖v‖ + 1e-6, stop early on allclose).
    pub fn leading_eigenvector(&self, iterations: usize) -> Vec<f32> {
        let mut v = vec![1f32; self.n];
        let mut y = vec![0f32; self.n];
        for _ in 0..iterations {
            self.matvec(&v, &mut y);
            normalise(&mut y);
            let done = allclose(&y, &v);
            std::mem::swap(&mut v, &mut y);
            if done {
                break;
            }
        }
        v
    }

    /// NMS seeds: i is a local maximum when conf_i ≥ conf_j for every j with Ds_ij < R; the
    /// values conf·is_local_max are sorted descending (stable) and the first `num` taken, so
    /// zeros (non-maxima) fill the list when there are too few maxima.
    pub fn pick_seeds(&self, conf: &[f32], num: usize) -> Vec<usize> {
        let score: Vec<f32> = (0..self.n)
            .into_par_iter()
            .map(|i| {
                let mut local_max = true;
                for_each_bit(self.near(i), |j| local_max &= conf[i] >= conf[j]);
                if local_max {
                    conf[i]
                } else {
                    0.0
                }
            })
            .collect();
        let mut order: Vec<usize> = (0..self.n).collect();
        order.sort_by(|&a, &b| score[b].total_cmp(&score[a]));
        order.truncate(num);
        order
    }

    /// Top-k1 correspondences of seed s by `SC2[s, j] = |tight[s] ∩ tight[j]| · hard[s, j]`,
    /// descending, ties by lower index; zero-valued entries fill the list in index order.
    #[cfg(test)]
    pub fn sc2_top_k(&self, s: usize, k1: usize) -> Vec<usize> {
        self.sc2_top_k_block(&[s], k1).pop().unwrap_or_default()
    }

    /// [`sc2_top_k`](Self::sc2_top_k) for a block of seeds at once. Candidates j are visited
    /// in the global order of decreasing `|tight[j]|` (ties by index), so for every seed the
    /// bound `min(|tight[j]|, |tight[s]|)` never increases and its scan stops once nothing left
    /// can enter its top-k1; the result does not depend on the visiting order. Each tight row
    /// is loaded once per block instead of once per seed.
    pub fn sc2_top_k_block(&self, seeds: &[usize], k1: usize) -> Vec<Vec<usize>> {
        let tc = &self.tight_count;
        // (value, index) ordered by value desc, then index asc.
        let mut tops: Vec<Vec<(u32, usize)>> = vec![Vec::with_capacity(k1 + 1); seeds.len()];
        let mut active: Vec<bool> = seeds.iter().map(|&s| tc[s] > 0).collect();
        let mut need: Vec<usize> = Vec::with_capacity(seeds.len());
        let mut rows: Vec<&[u64]> = Vec::with_capacity(seeds.len());
        let mut vals = vec![0u32; seeds.len()];
        for &j in &self.by_tight {
            let j = j as usize;
            let tj = self.tight(j);
            let mut any = false;
            need.clear();
            rows.clear();
            for (b, &s) in seeds.iter().enumerate() {
                if !active[b] {
                    continue;
                }
                let top = &tops[b];
                let bound = tc[j].min(tc[s]);
                if top.len() == k1 && bound < top[k1 - 1].0 {
                    active[b] = false;
                    continue;
                }
                any = true;
                if bit(self.hard(s), j) {
                    need.push(b);
                    rows.push(self.tight(s));
                }
            }
            if !any {
                break;
            }
            let vals = &mut vals[..need.len()];
            match self.isa {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: the CPU supports AVX-512F and VPOPCNTDQ (checked by `bitset_isa`);
                // rows are `stride` words, a multiple of 8.
                Isa::Avx512 => unsafe {
                    crate::simd::x86_64_avx512::and_popcount_many(tj, &rows, vals)
                },
                _ => {
                    for (v, r) in vals.iter_mut().zip(&rows) {
                        *v = crate::simd::and_popcount(self.isa, r, tj);
                    }
                }
            }
            for (&b, &v) in need.iter().zip(vals.iter()) {
                if v == 0 {
                    continue;
                }
                let top = &mut tops[b];
                let pos = top.partition_point(|&(tv, tl)| tv > v || (tv == v && tl < j));
                if pos < k1 {
                    top.insert(pos, (v, j));
                    top.truncate(k1);
                }
            }
        }
        tops.into_iter()
            .map(|top| {
                let mut knn: Vec<usize> = top.iter().map(|&(_, j)| j).collect();
                if knn.len() < k1 {
                    let mut chosen = knn.clone();
                    chosen.sort_unstable();
                    for j in 0..self.n {
                        if knn.len() == k1 {
                            break;
                        }
                        if chosen.binary_search(&j).is_err() {
                            knn.push(j);
                        }
                    }
                }
                knn
            })
            .collect()
    }

    /// Second stage: within the k1 set, row 0 of `hard @ hard` (local hard from the global
    /// bitset, which uses the same distance formula), top-k2 descending, stable.
    pub fn second_stage(&self, knn: &[usize], k2: usize) -> Vec<usize> {
        let h0 = self.hard(knn[0]);
        let score: Vec<u32> = knn
            .iter()
            .map(|&m| {
                knn.iter()
                    .filter(|&&l| bit(h0, l) && bit(self.hard(l), m))
                    .count() as u32
            })
            .collect();
        let mut order: Vec<usize> = (0..knn.len()).collect();
        order.sort_by(|&a, &b| score[b].cmp(&score[a]));
        order.truncate(k2);
        order.into_iter().map(|k| knn[k]).collect()
    }
}
