//! The tests' seeded generator: one linear congruential step (Knuth's MMIX constants) with the
//! output mappings the tests read. Every test that draws random data draws it from here, so a
//! failing case is reproduced by its seed alone.

use nalgebra::Point3;

/// A seeded generator; the seed is the whole state (`Lcg(seed)`).
#[derive(Clone, Debug)]
pub struct Lcg(pub u64);

impl Lcg {
    /// The next state.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0
    }

    /// Uniform in [0, 1) with 24 bits: exact in f32.
    pub fn unit_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [0, 1) from 31 bits, rounded to f32.
    pub fn unit31_f32(&mut self) -> f32 {
        ((self.next_u64() >> 33) as f64 / (1u64 << 31) as f64) as f32
    }

    /// Uniform in [0, 1) with 53 bits.
    pub fn unit_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// 31 uniform bits.
    pub fn u31(&mut self) -> u32 {
        (self.next_u64() >> 33) as u32
    }

    /// Uniform in [-1, 1) with 24 bits.
    pub fn signed_f32(&mut self) -> f32 {
        self.unit_f32() * 2.0 - 1.0
    }

    /// A point uniform in [0, scale)^3.
    pub fn point(&mut self, scale: f32) -> Point3<f32> {
        Point3::new(
            self.unit_f32() * scale,
            self.unit_f32() * scale,
            self.unit_f32() * scale,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The mappings are the ones the tests' private generators used, value for value.
    #[test]
    fn the_mappings_match_the_former_private_generators() {
        let step = |s: &mut u64| {
            *s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            *s
        };
        let (mut s, mut g) = (12345u64, Lcg(12345));
        for _ in 0..1000 {
            let x = step(&mut s);
            assert_eq!(g.clone().next_u64(), x);
            assert_eq!(g.clone().unit_f32(), (x >> 40) as f32 / (1u64 << 24) as f32);
            assert_eq!(
                g.clone().unit_f32(),
                ((x >> 40) as f64 / (1u64 << 24) as f64) as f32
            );
            assert_eq!(
                g.clone().unit31_f32(),
                (x >> 33) as f32 / (1u64 << 31) as f32
            );
            assert_eq!(g.clone().u31(), (x >> 33) as u32);
            assert_eq!(g.clone().unit_f64(), (x >> 11) as f64 / (1u64 << 53) as f64);
            g.next_u64();
        }
    }
}
