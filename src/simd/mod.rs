//! Vectorised kernels shared by the estimator and the fusion, one file per instruction set,
//! and the one run-time CPU feature detector they all use.
//!
//! A kernel family states the features it needs as one [`Isa`] rule on [`Features`]
//! ([`Features::float_isa`], [`Features::bitset_isa`]); callers pick the kernel with a `match`
//! on that [`Isa`]. Loops that only need the compiler to auto-vectorise stay next to their
//! algorithm, as `#[target_feature]` copies of one `#[inline(always)]` body, dispatched on the
//! same [`Isa`].

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

/// This CPU's features (detected on the first call).
pub fn features() -> Features {
    static F: OnceLock<Features> = OnceLock::new();
    *F.get_or_init(detect)
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
