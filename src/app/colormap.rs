//! Colours shared by every panel: the fixed cloud colours, categorical match colours and the
//! turbo colormap for scores.

/// Default source colour (yellow) and target colour (blue), as in the paper's figures.
pub const SOURCE_RGB: [u8; 3] = [255, 200, 20];
pub const TARGET_RGB: [u8; 3] = [40, 120, 255];
pub const INLIER_RGB: [u8; 3] = [40, 200, 70];
pub const OUTLIER_RGB: [u8; 3] = [230, 50, 40];
pub const HIGHLIGHT_RGB: [u8; 3] = [255, 0, 255];

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

pub fn hsv(h: f32, s: f32, v: f32) -> [u8; 3] {
    let h6 = h.fract() * 6.0;
    let c = v * s;
    let x = c * (1.0 - ((h6 % 2.0) - 1.0).abs());
    let (r, g, b) = match h6 as i32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    let q = |u: f32| ((u + m) * 255.0).round() as u8;
    [q(r), q(g), q(b)]
}

pub fn to_color32(c: [u8; 3]) -> eframe::egui::Color32 {
    eframe::egui::Color32::from_rgb(c[0], c[1], c[2])
}

#[cfg(test)]
mod tests {
    use super::*;
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
