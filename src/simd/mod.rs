//! Vectorised kernels shared by the estimator and the fusion, one file per instruction set,
//! and the one run-time CPU feature detector they all use.
//!
//! A kernel family states the features it needs as one [`Isa`] rule on [`Features`]
//! ([`Features::float_isa`], [`Features::bitset_isa`]); callers pick the kernel with a `match`
//! on that [`Isa`] (or through a dispatcher here: [`and_popcount`], [`compat_row`]). A kernel
//! that only needs the compiler to auto-vectorise is one `#[inline(always)]` body in
//! `scalar.rs` with `#[target_feature]` copies in the ISA files (SC2-PCR's [`compat_row`]);
//! the fused softmax / Noisy-AND row loops of `fusion/fused.rs` are still such copies next to
//! their algorithm.

pub mod scalar;
#[cfg(target_arch = "x86_64")]
pub mod x86_64_avx2;
#[cfg(target_arch = "x86_64")]
pub mod x86_64_avx512;

use std::sync::OnceLock;

/// The widest usable kernel of a family on this CPU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    Avx512,
    Avx2,
    Scalar,
}

/// The CPU features the kernels use, detected once per process.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Features {
    pub avx2: bool,
    pub fma: bool,
    pub popcnt: bool,
    pub avx512f: bool,
    pub avx512bw: bool,
    pub avx512vl: bool,
    pub avx512dq: bool,
    pub avx512vpopcntdq: bool,
}

/// This CPU's features (detected on the first call), capped by `CGENREG_SIMD` when set:
/// `avx2` hides AVX-512, `scalar` hides every vector extension (to run or time the narrower
/// kernels on a wider CPU; every kernel gives the same bits).
pub fn features() -> Features {
    static F: OnceLock<Features> = OnceLock::new();
    *F.get_or_init(|| cap(detect(), std::env::var("CGENREG_SIMD").ok().as_deref()))
}

fn cap(f: Features, limit: Option<&str>) -> Features {
    let no512 = Features {
        avx512f: false,
        avx512bw: false,
        avx512vl: false,
        avx512dq: false,
        avx512vpopcntdq: false,
        ..f
    };
    match limit {
        Some("avx2") => no512,
        Some("scalar") => Features::default(),
        _ => f,
    }
}

#[cfg(target_arch = "x86_64")]
fn detect() -> Features {
    Features {
        avx2: is_x86_feature_detected!("avx2"),
        fma: is_x86_feature_detected!("fma"),
        popcnt: is_x86_feature_detected!("popcnt"),
        avx512f: is_x86_feature_detected!("avx512f"),
        avx512bw: is_x86_feature_detected!("avx512bw"),
        avx512vl: is_x86_feature_detected!("avx512vl"),
        avx512dq: is_x86_feature_detected!("avx512dq"),
        avx512vpopcntdq: is_x86_feature_detected!("avx512vpopcntdq"),
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn detect() -> Features {
    Features::default()
}

impl Features {
    /// Float row kernels (the fused softmax / Noisy-AND rows): AVX-512 F+BW+VL+DQ, else AVX2.
    pub fn float_isa(&self) -> Isa {
        if self.avx512f && self.avx512bw && self.avx512vl && self.avx512dq {
            Isa::Avx512
        } else if self.avx2 {
            Isa::Avx2
        } else {
            Isa::Scalar
        }
    }

    /// Dot products as exact fused multiply-add chains ([`dot_rows`]): AVX-512F with AVX2 +
    /// FMA (8 x 32 tiles), else AVX2 + FMA, else [`Isa::Scalar`], where `dot_rows` is correct
    /// but slow (a C library call per product) and callers keep a faster fallback of their own.
    pub fn fma_isa(&self) -> Isa {
        if self.avx512f && self.avx2 && self.fma {
            Isa::Avx512
        } else if self.avx2 && self.fma {
            Isa::Avx2
        } else {
            Isa::Scalar
        }
    }

    /// Bit-set kernels and SC2-PCR's compatibility rows: AVX-512 F+BW+VL+VPOPCNTDQ with POPCNT
    /// and FMA, else AVX2 with POPCNT and FMA.
    pub fn bitset_isa(&self) -> Isa {
        if self.avx512f
            && self.avx512bw
            && self.avx512vl
            && self.avx512vpopcntdq
            && self.popcnt
            && self.fma
        {
            Isa::Avx512
        } else if self.avx2 && self.popcnt && self.fma {
            Isa::Avx2
        } else {
            Isa::Scalar
        }
    }
}

/// `|a & b|` (bits set in both) with the kernel `isa` selects; `isa` must come from
/// [`Features::bitset_isa`] of this CPU (or be [`Isa::Scalar`]).
#[inline(always)]
pub fn and_popcount(isa: Isa, a: &[u64], b: &[u64]) -> u32 {
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the CPU supports these features (bitset_isa checked them at run time).
        Isa::Avx512 => return unsafe { x86_64_avx512::and_popcount(a, b) },
        Isa::Avx2 => return unsafe { x86_64_avx2::and_popcount(a, b) },
        Isa::Scalar => {}
    }
    let _ = isa;
    scalar::and_popcount(a, b)
}

/// [`scalar::dot_rows`] (rows of `a` against the transpose `bt` of b, exact FMA chains) with
/// the kernel `isa` selects; `isa` must come from [`Features::fma_isa`] of this CPU (or be
/// [`Isa::Scalar`]). Every kernel gives the same bits.
#[inline(always)]
pub fn dot_rows(isa: Isa, a: &[f32], d: usize, bt: &[f32], m: usize, out: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the CPU supports AVX2 and FMA (fma_isa checked them at run time).
        Isa::Avx512 => return unsafe { x86_64_avx512::dot_rows(a, d, bt, m, out) },
        // SAFETY: as above (AVX2 and FMA).
        Isa::Avx2 => return unsafe { x86_64_avx2::dot_rows(a, d, bt, m, out) },
        Isa::Scalar => {}
    }
    let _ = isa;
    scalar::dot_rows(a, d, bt, m, out)
}

/// The endpoints of n correspondences as structure-of-arrays f32: source x, y, z and target
/// x, y, z, every column of length n.
#[derive(Clone, Copy, Debug)]
pub struct PairColumns<'a> {
    pub src: [&'a [f32]; 3],
    pub tgt: [&'a [f32]; 3],
}

impl PairColumns<'_> {
    /// The number of correspondences.
    pub fn len(&self) -> usize {
        self.src[0].len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// SC2-PCR's compatibility row ([`scalar::compat_row`]) with the kernel `isa` selects; `isa`
/// must come from [`Features::bitset_isa`] of this CPU (or be [`Isa::Scalar`]). Every kernel
/// gives the same bits and values (same arithmetic, no contraction).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn compat_row(
    isa: Isa,
    p: PairColumns,
    i: usize,
    d: f32,
    nms: f32,
    w0: usize,
    words: usize,
    rows: (&mut [u64], &mut [u64], &mut [u64]),
    vals: &mut Vec<(u32, f32)>,
) {
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the CPU supports these features (bitset_isa checked them at run time).
        Isa::Avx512 => {
            return unsafe { x86_64_avx512::compat_row(p, i, d, nms, w0, words, rows, vals) }
        }
        Isa::Avx2 => {
            return unsafe { x86_64_avx2::compat_row(p, i, d, nms, w0, words, rows, vals) }
        }
        Isa::Scalar => {}
    }
    let _ = isa;
    scalar::compat_row(p, i, d, nms, w0, words, rows, vals)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cgenreg_simd_caps_the_detected_features() {
        let all = Features {
            avx2: true,
            fma: true,
            popcnt: true,
            avx512f: true,
            avx512bw: true,
            avx512vl: true,
            avx512dq: true,
            avx512vpopcntdq: true,
        };
        assert_eq!(cap(all, None), all);
        assert_eq!(cap(all, Some("avx512")), all);
        assert_eq!(cap(all, Some("avx2")).float_isa(), Isa::Avx2);
        assert_eq!(cap(all, Some("avx2")).bitset_isa(), Isa::Avx2);
        assert_eq!(cap(all, Some("scalar")).float_isa(), Isa::Scalar);
        assert_eq!(cap(all, Some("scalar")).bitset_isa(), Isa::Scalar);
    }

    #[test]
    fn rules_fall_back_in_order() {
        let none = Features::default();
        assert_eq!(
            (none.float_isa(), none.bitset_isa()),
            (Isa::Scalar, Isa::Scalar)
        );
        let avx2 = Features {
            avx2: true,
            fma: true,
            popcnt: true,
            ..none
        };
        assert_eq!(
            (avx2.float_isa(), avx2.bitset_isa()),
            (Isa::Avx2, Isa::Avx2)
        );
        // AVX2 without POPCNT: float kernels only
        let f = Features {
            popcnt: false,
            ..avx2
        };
        assert_eq!((f.float_isa(), f.bitset_isa()), (Isa::Avx2, Isa::Scalar));
        // AVX-512 with DQ but no VPOPCNTDQ (e.g. Skylake-X): float 512, bit sets AVX2
        let skx = Features {
            avx512f: true,
            avx512bw: true,
            avx512vl: true,
            avx512dq: true,
            ..avx2
        };
        assert_eq!(
            (skx.float_isa(), skx.bitset_isa()),
            (Isa::Avx512, Isa::Avx2)
        );
    }

    #[test]
    fn popcount_kernels_agree_with_scalar() {
        let (seed, mut rng) = crate::estimate::rng::seeded_for_test("simd-popcount");
        for len in [0usize, 1, 7, 8, 9, 63, 64, 200] {
            let a: Vec<u64> = (0..len).map(|_| rng.next_u64()).collect();
            let b: Vec<u64> = (0..len).map(|_| rng.next_u64()).collect();
            let want = scalar::and_popcount(&a, &b);
            for isa in [Isa::Scalar, features().bitset_isa()] {
                assert_eq!(
                    and_popcount(isa, &a, &b),
                    want,
                    "len {len}, {isa:?}, seed {seed}"
                );
            }
        }
    }

    #[test]
    fn and_popcount_many_agrees_with_scalar() {
        let a: Vec<u64> = (0..131u64)
            .map(|k| k.wrapping_mul(0x9e37_79b9_7f4a_7c15))
            .collect();
        let b: Vec<u64> = (0..131u64)
            .map(|k| (k + 7).wrapping_mul(0xc2b2_ae3d_27d4_eb4f))
            .collect();
        #[cfg(target_arch = "x86_64")]
        if features().bitset_isa() == Isa::Avx512 {
            let pad = |v: &[u64]| {
                let mut p = v.to_vec();
                p.resize(136, 0);
                p
            };
            let rows: Vec<Vec<u64>> = (0..6u64)
                .map(|r| {
                    pad(&b
                        .iter()
                        .map(|x| x.rotate_left(r as u32 * 7))
                        .collect::<Vec<_>>())
                })
                .collect();
            let refs: Vec<&[u64]> = rows.iter().map(|r| r.as_slice()).collect();
            let mut out = vec![0u32; 6];
            // SAFETY: checked AVX-512 support; rows are 136 = 17 x 8 words.
            unsafe { x86_64_avx512::and_popcount_many(&pad(&a), &refs, &mut out) };
            for (o, r) in out.iter().zip(&rows) {
                assert_eq!(*o, scalar::and_popcount(&pad(&a), r));
            }
        }
    }

    #[test]
    fn compat_row_kernels_agree_with_scalar() {
        let (seed, mut rng) = crate::estimate::rng::seeded_for_test("simd-compat-row");
        for n in [1usize, 5, 64, 65, 200] {
            // Points in a 0.3 m cube, so that all three relations have set and clear bits.
            let mut col = || -> Vec<f32> {
                (0..n)
                    .map(|_| rng.next_u64() as f32 / u64::MAX as f32 * 0.3)
                    .collect()
            };
            let (s, t) = ([col(), col(), col()], [col(), col(), col()]);
            let p = PairColumns {
                src: [&s[0], &s[1], &s[2]],
                tgt: [&t[0], &t[1], &t[2]],
            };
            let words = n.div_ceil(64);
            let run = |isa: Isa, i: usize| {
                let (mut h, mut tt, mut r) =
                    (vec![0u64; words], vec![0u64; words], vec![0u64; words]);
                let mut vals = Vec::new();
                compat_row(
                    isa,
                    p,
                    i,
                    0.1,
                    0.1,
                    i / 64,
                    words,
                    (&mut h, &mut tt, &mut r),
                    &mut vals,
                );
                (
                    h,
                    tt,
                    r,
                    vals.iter()
                        .map(|&(j, v)| (j, v.to_bits()))
                        .collect::<Vec<_>>(),
                )
            };
            for i in 0..n {
                let want = run(Isa::Scalar, i);
                assert_eq!(
                    run(features().bitset_isa(), i),
                    want,
                    "n {n}, row {i}, seed {seed}"
                );
                // Spot check against the formula.
                for j in (i / 64) * 64..n {
                    let ds = ((s[0][i] - s[0][j]).powi(2)
                        + (s[1][i] - s[1][j]).powi(2)
                        + (s[2][i] - s[2][j]).powi(2))
                    .sqrt();
                    let dt = ((t[0][i] - t[0][j]).powi(2)
                        + (t[1][i] - t[1][j]).powi(2)
                        + (t[2][i] - t[2][j]).powi(2))
                    .sqrt();
                    let c = (ds - dt).abs();
                    let b = |row: &[u64]| row[j / 64] >> (j % 64) & 1 == 1;
                    if (c - 0.1).abs() > 1e-5 {
                        assert_eq!(b(&want.0), c < 0.1, "hard ({i}, {j}), seed {seed}");
                    }
                    if (c - 0.05).abs() > 1e-5 {
                        assert_eq!(b(&want.1), c < 0.05, "tight ({i}, {j}), seed {seed}");
                    }
                    if (ds - 0.1).abs() > 1e-5 {
                        assert_eq!(b(&want.2), ds < 0.1, "near ({i}, {j}), seed {seed}");
                    }
                }
            }
        }
    }
}
