//! Image to tensor conversions shared by the models. Tensors are planar CHW f32, row-major.

use image::RgbImage;

/// RGB u8 -> planar (3, H, W) with `f(u8)` applied per value.
pub fn to_chw(img: &RgbImage, f: impl Fn(u8) -> f32) -> Vec<f32> {
    let (w, h) = img.dimensions();
    let plane = (w * h) as usize;
    let mut out = vec![0.0f32; 3 * plane];
    for (i, p) in img.pixels().enumerate() {
        out[i] = f(p[0]);
        out[plane + i] = f(p[1]);
        out[2 * plane + i] = f(p[2]);
    }
    out
}

/// Bilinear resize of planar (C, H, W) data, torch `interpolate(bilinear, align_corners=False,
/// antialias=False)` semantics (the resize XFeat applies to sizes that are not multiples of 32).
pub fn resize_bilinear_chw(
    src: &[f32],
    c: usize,
    (w, h): (usize, usize),
    (ow, oh): (usize, usize),
) -> Vec<f32> {
    let (sw, sh) = (w as f32 / ow as f32, h as f32 / oh as f32);
    let idx = |o: usize, s: f32, n: usize| {
        let r = (s * (o as f32 + 0.5) - 0.5).max(0.0);
        let i0 = (r as usize).min(n - 1);
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, if i1 == i0 { 0.0 } else { r - i0 as f32 })
    };
    let xs: Vec<_> = (0..ow).map(|x| idx(x, sw, w)).collect();
    let mut out = vec![0.0f32; c * ow * oh];
    for ch in 0..c {
        let plane = &src[ch * w * h..(ch + 1) * w * h];
        for y in 0..oh {
            let (y0, y1, fy) = idx(y, sh, h);
            let (r0, r1) = (&plane[y0 * w..(y0 + 1) * w], &plane[y1 * w..(y1 + 1) * w]);
            let orow = &mut out[(ch * oh + y) * ow..(ch * oh + y + 1) * ow];
            for (o, &(x0, x1, fx)) in orow.iter_mut().zip(&xs) {
                let top = r0[x0] + fx * (r0[x1] - r0[x0]);
                let bot = r1[x0] + fx * (r1[x1] - r1[x0]);
                *o = top + fy * (bot - top);
            }
        }
    }
    out
}

/// Python's `round()` (half to even), as PIL size computations use it.
pub fn round_half_even(x: f64) -> i64 {
    let f = x.floor();
    let fi = f as i64;
    match (x - f).partial_cmp(&0.5) {
        Some(std::cmp::Ordering::Greater) => fi + 1,
        Some(std::cmp::Ordering::Less) => fi,
        _ => fi + fi.rem_euclid(2),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_even_rounding_matches_python() {
        for (x, want) in [
            (0.5, 0),
            (1.5, 2),
            (2.5, 2),
            (3.5, 4),
            (375.4666, 375),
            (374.5, 374),
            (-0.5, 0),
            (2.4, 2),
            (2.6, 3),
        ] {
            assert_eq!(round_half_even(x), want, "round({x})");
        }
    }

    #[test]
    fn bilinear_identity_and_constant() {
        let src: Vec<f32> = (0..2 * 6 * 4).map(|i| i as f32).collect();
        assert_eq!(resize_bilinear_chw(&src, 2, (6, 4), (6, 4)), src);
        let flat = vec![3.0f32; 3 * 10 * 7];
        let out = resize_bilinear_chw(&flat, 3, (10, 7), (4, 3));
        assert!(out.iter().all(|&v| (v - 3.0).abs() < 1e-6));
    }
}
