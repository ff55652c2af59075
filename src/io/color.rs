//! Colour conversions shared by the images the crate makes (the built-in generator's palettes)
//! and draws (the inspector's match colours): one implementation of each formula.

/// HSV to RGB, every channel in [0, 1]: hue in degrees (any value, taken modulo 360),
/// saturation and value in [0, 1].
pub fn hsv_to_rgb(h_deg: f32, s: f32, v: f32) -> [f32; 3] {
    let h = h_deg.rem_euclid(360.0) / 60.0;
    let c = v * s;
    let x = c * (1.0 - ((h % 2.0) - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [r + m, g + m, b + m]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primaries_and_wrap_around() {
        let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
        assert!(close(hsv_to_rgb(0.0, 1.0, 1.0), [1.0, 0.0, 0.0]));
        assert!(close(hsv_to_rgb(120.0, 1.0, 1.0), [0.0, 1.0, 0.0]));
        assert!(close(hsv_to_rgb(240.0, 1.0, 1.0), [0.0, 0.0, 1.0]));
        assert!(close(hsv_to_rgb(360.0 + 60.0, 1.0, 1.0), [1.0, 1.0, 0.0]));
        assert!(close(hsv_to_rgb(-120.0, 1.0, 1.0), [0.0, 0.0, 1.0]));
        // no saturation: grey at the value
        assert!(close(hsv_to_rgb(77.0, 0.0, 0.4), [0.4, 0.4, 0.4]));
    }
}
