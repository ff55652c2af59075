//! Colours shared by every panel: the fixed cloud colours, categorical match colours and the
//! turbo colormap for scores.

/// Default source colour (yellow) and target colour (blue), as in the paper's figures.
pub const SOURCE_RGB: [u8; 3] = [255, 200, 20];
pub const TARGET_RGB: [u8; 3] = [40, 120, 255];
pub const INLIER_RGB: [u8; 3] = [40, 200, 70];
pub const OUTLIER_RGB: [u8; 3] = [230, 50, 40];
pub const HIGHLIGHT_RGB: [u8; 3] = [255, 0, 255];
/// A cloud in the fixed colour while the other shows a colour map: grey, never a map colour
/// (the fixed blue of the target is close to turbo's low end).
pub const NEUTRAL_RGB: [u8; 3] = [175, 175, 175];

/// Rank quantile of each value in [0, 1] (0: the lowest, 1: the highest; ties share the
/// lower rank): confidence colours spread over the whole map even when most scores sit near
/// one value (Noisy-AND scores about 1.0 for most matches).
pub fn rank_quantiles(v: &[f32]) -> Vec<f32> {
    let n = v.len();
    if n < 2 {
        return vec![1.0; n];
    }
    let mut idx: Vec<usize> = (0..n).collect();
    idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let mut q = vec![0.0; n];
    let mut r = 0;
    for k in 0..n {
        if k > 0 && v[idx[k]] != v[idx[k - 1]] {
            r = k;
        }
        q[idx[k]] = r as f32 / (n - 1) as f32;
    }
    q
}

/// The value at quantile `q` of `v` (nearest rank), for a colour bar's tick labels.
pub fn quantile_value(v: &[f32], q: f32) -> Option<f32> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f32::total_cmp);
    let i = ((s.len() - 1) as f32 * q.clamp(0.0, 1.0)).round() as usize;
    Some(s[i])
}

/// Polynomial fit of Google's turbo colormap, `t` in [0, 1].
pub fn turbo(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0) as f64;
    let r = 0.13572138
        + t * (4.61539260
            + t * (-42.66032258 + t * (132.13108234 + t * (-152.94239396 + t * 59.28637943))));
    let g = 0.09140261
        + t * (2.19418839
            + t * (4.84296658 + t * (-14.18503333 + t * (4.27729857 + t * 2.82956604))));
    let b = 0.10667330
        + t * (12.64194608
            + t * (-60.58204836 + t * (110.36276771 + t * (-89.90310912 + t * 27.34824973))));
    let c = |x: f64| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    [c(r), c(g), c(b)]
}

/// Distinct colour for the `i`-th match of a categorical subset (golden-angle hue walk).
pub fn categorical(i: usize) -> [u8; 3] {
    let h = (i as f32 * 0.618_034).fract();
    hsv(h, 0.85, 0.95)
}

/// HSV (hue in turns) to 8-bit RGB ([`crate::io::color::hsv_to_rgb`]).
pub fn hsv(h: f32, s: f32, v: f32) -> [u8; 3] {
    let q = |u: f32| (u * 255.0).round() as u8;
    let [r, g, b] = crate::io::color::hsv_to_rgb(h * 360.0, s, v);
    [q(r), q(g), q(b)]
}

pub fn to_color32(c: [u8; 3]) -> eframe::egui::Color32 {
    eframe::egui::Color32::from_rgb(c[0], c[1], c[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rank_quantiles_spread_saturated_scores() {
        // scores crowded at 1.0 (Noisy-AND) still span the map by rank
        let v = [0.999_9, 1.0, 0.999_8, 0.2, 1.0];
        let q = rank_quantiles(&v);
        assert_eq!(q, vec![0.5, 0.75, 0.25, 0.0, 0.75]);
        assert_eq!(quantile_value(&v, 0.0), Some(0.2));
        assert_eq!(quantile_value(&v, 1.0), Some(1.0));
        assert_eq!(rank_quantiles(&[0.3]), vec![1.0]);
    }
    #[test]
    fn turbo_endpoints_and_categorical_distinct() {
        let lo = turbo(0.15);
        let hi = turbo(1.0);
        assert!(lo[2] > lo[0], "turbo is blue near the low end: {lo:?}");
        assert!(hi[0] > hi[2], "turbo ends red-ish: {hi:?}");
        let mid = turbo(0.5);
        assert!(mid[1] > 150, "turbo is green in the middle: {mid:?}");
        for i in 0..8 {
            for j in 0..i {
                let (a, b) = (categorical(i), categorical(j));
                let d: i32 = (0..3).map(|k| (a[k] as i32 - b[k] as i32).abs()).sum();
                assert!(d > 40, "colours {i} and {j} too close");
            }
        }
    }
}
