//! `builtin-depthshade-v1`: a deterministic stand-in for the WFM so the whole pipeline runs on
//! any machine without a GPU or a download. It is NOT a world foundation model and it is
//! labelled as such in every provenance record.
//!
//! It sees only the depth-control video (8-bit normalised inverse depth, near = bright) and the
//! prompt; never real RGB, never ground truth. Per frame, at the output size (960x704 like
//! Cosmos, input upsampled bilinearly with half-pixel centres):
//! 1. normalised convolution (a 5x5 box, twice) smooths the 8-bit terraces of valid pixels;
//! 2. pseudo-normals from the inverse-depth gradient, `n = normalize(-k gx, -k gy, 1)`;
//! 3. albedo from surface orientation (facing / sideways / horizontal surfaces get three
//!    colours of a palette derived from a BLAKE3 hash of the prompt);
//! 4. Lambert shading with a fixed light in camera coordinates, ambient occlusion from how much
//!    farther a pixel is than its 31x31 neighbourhood, a little distance fog;
//! 5. dark lines on occlusion edges (large inverse-depth steps) and creases (normal changes);
//! 6. invalid/farthest pixels (grey 0) get a dark "void" colour.
//!
//! Everything is a function of local depth structure in camera coordinates, so the appearance
//! of a surface changes smoothly between neighbouring frames (consistent across nearby views),
//! but it carries no surface texture: descriptors find depth edges and creases, not paint.

use super::backend::{now_unix, GenerateRequest, Generation, Provenance, WfmBackend};
use crate::error::{Error, Result};
use crate::io::color::hsv_to_rgb as hsv;
use image::RgbImage;
use rayon::prelude::*;

pub const NAME: &str = "builtin-depthshade-v1";

#[derive(Clone, Debug)]
pub struct DepthShadeBackend {
    pub width: u32,
    pub height: u32,
}

impl Default for DepthShadeBackend {
    fn default() -> Self {
        DepthShadeBackend {
            width: 960,
            height: 704,
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Palette {
    face: [f32; 3],
    side: [f32; 3],
    flat: [f32; 3],
    fog: [f32; 3],
    void: [f32; 3],
}

fn palette(prompt: &str) -> (Palette, String) {
    let h = blake3::hash(prompt.as_bytes());
    let b = h.as_bytes();
    let hue = (u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0) * 360.0;
    let sat = 0.25 + 0.3 * (b[2] as f32 / 255.0);
    (
        Palette {
            face: hsv(hue, sat, 0.9),
            side: hsv(hue + 130.0, sat * 0.8, 0.8),
            flat: hsv(hue + 230.0, sat * 0.7, 0.7),
            fog: hsv(hue + 30.0, 0.1, 0.35),
            void: [0.08, 0.08, 0.09],
        },
        h.to_hex()[..16].to_string(),
    )
}

/// Bilinear resize of a plane with half-pixel centres.
fn resize_plane(src: &[f32], sw: usize, sh: usize, w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0.0; w * h];
    let (fx, fy) = (sw as f32 / w as f32, sh as f32 / h as f32);
    let xs: Vec<(usize, usize, f32)> = (0..w)
        .map(|x| {
            let f = ((x as f32 + 0.5) * fx - 0.5).max(0.0);
            let x0 = (f as usize).min(sw - 1);
            (x0, (x0 + 1).min(sw - 1), f - x0 as f32)
        })
        .collect();
    for y in 0..h {
        let f = ((y as f32 + 0.5) * fy - 0.5).max(0.0);
        let y0 = (f as usize).min(sh - 1);
        let y1 = (y0 + 1).min(sh - 1);
        let ty = f - y0 as f32;
        for (x, &(x0, x1, tx)) in xs.iter().enumerate() {
            let a = src[y0 * sw + x0] + (src[y0 * sw + x1] - src[y0 * sw + x0]) * tx;
            let b = src[y1 * sw + x0] + (src[y1 * sw + x1] - src[y1 * sw + x0]) * tx;
            out[y * w + x] = a + (b - a) * ty;
        }
    }
    out
}

/// Box filter of radius r (window 2r+1, clamped at borders) via running sums, separable.
fn box_blur(src: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let mut tmp = vec![0.0f32; w * h];
    let mut row = vec![0.0f64; w + 1];
    for y in 0..h {
        for x in 0..w {
            row[x + 1] = row[x] + src[y * w + x] as f64;
        }
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r + 1).min(w));
            tmp[y * w + x] = ((row[b] - row[a]) / (b - a) as f64) as f32;
        }
    }
    // Vertical pass with a running sum of whole rows (contiguous memory access).
    let mut out = vec![0.0f32; w * h];
    let mut acc = vec![0.0f64; w];
    let add = |acc: &mut [f64], row: &[f32], sign: f64| {
        for (a, &v) in acc.iter_mut().zip(row) {
            *a += sign * v as f64;
        }
    };
    for yy in 0..=r.min(h - 1) {
        add(&mut acc, &tmp[yy * w..(yy + 1) * w], 1.0);
    }
    for y in 0..h {
        let count = ((y + r).min(h - 1) - y.saturating_sub(r) + 1) as f64;
        for (o, a) in out[y * w..(y + 1) * w].iter_mut().zip(&acc) {
            *o = (a / count) as f32;
        }
        if y + r + 1 < h {
            add(&mut acc, &tmp[(y + r + 1) * w..(y + r + 2) * w], 1.0);
        }
        if y >= r {
            add(&mut acc, &tmp[(y - r) * w..(y - r + 1) * w], -1.0);
        }
    }
    out
}

/// Blur of the valid values only: blur(v * m) / blur(m).
fn masked_blur(v: &[f32], m: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let vm: Vec<f32> = v.iter().zip(m).map(|(a, b)| a * b).collect();
    let num = box_blur(&vm, w, h, r);
    let den = box_blur(m, w, h, r);
    num.iter()
        .zip(&den)
        .map(|(n, d)| if *d > 1e-4 { n / d } else { 0.0 })
        .collect()
}

fn shade_frame(frame: &RgbImage, w: usize, h: usize, pal: &Palette) -> RgbImage {
    let (sw, sh) = (frame.width() as usize, frame.height() as usize);
    let raw: Vec<f32> = frame.pixels().map(|p| p[0] as f32 / 255.0).collect();
    let valid_raw: Vec<f32> = raw
        .iter()
        .map(|&v| if v > 0.0 { 1.0 } else { 0.0 })
        .collect();
    let mut s = resize_plane(&raw, sw, sh, w, h);
    let mut m = resize_plane(&valid_raw, sw, sh, w, h);
    // Values blended with invalid pixels are not depth: renormalise them by the blended mask.
    for (v, mm) in s.iter_mut().zip(m.iter_mut()) {
        if *mm > 0.5 {
            *v /= *mm;
            *mm = 1.0;
        } else {
            *v = 0.0;
            *mm = 0.0;
        }
    }
    let scale = w.max(h) as f32 / 960.0;
    let r_small = ((2.0 * scale).round() as usize).max(1);
    let s1 = masked_blur(&s, &m, w, h, r_small);
    let s2 = masked_blur(&s1, &m, w, h, r_small);
    let big = masked_blur(&s2, &m, w, h, ((15.0 * scale).round() as usize).max(2));
    let k = 350.0 * scale;
    let light = {
        let l = [-0.35f32, -0.55, 0.75];
        let n = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        [l[0] / n, l[1] / n, l[2] / n]
    };
    // Pseudo-normals once per pixel (central differences of the smoothed inverse depth).
    let mut normals = vec![[0.0f32, 0.0, 1.0]; w * h];
    for y in 0..h {
        let (yu, yd) = (y.saturating_sub(1), (y + 1).min(h - 1));
        let dy = (yd - yu).max(1) as f32;
        for x in 0..w {
            let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let gx = (s2[y * w + xr] - s2[y * w + xl]) / (xr - xl).max(1) as f32;
            let gy = (s2[yd * w + x] - s2[yu * w + x]) / dy;
            let (nx, ny) = (-k * gx, -k * gy);
            let l = (nx * nx + ny * ny + 1.0).sqrt().recip();
            normals[y * w + x] = [nx * l, ny * l, l];
        }
    }
    let normal = |x: usize, y: usize| normals[y * w + x];
    let mut out = RgbImage::new(w as u32, h as u32);
    let buf: &mut [u8] = out.as_mut();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let c = if m[i] == 0.0 {
                pal.void
            } else {
                let n = normal(x, y);
                // Crease: how much the normal turns over 2 px.
                let (xr, yd) = ((x + 2).min(w - 1), (y + 2).min(h - 1));
                let (nr, nd) = (normal(xr, y), normal(x, yd));
                let crease = ((1.0 - (n[0] * nr[0] + n[1] * nr[1] + n[2] * nr[2]))
                    + (1.0 - (n[0] * nd[0] + n[1] * nd[1] + n[2] * nd[2])))
                    .min(1.0);
                // Occlusion edge: a step in the unsmoothed inverse depth or next to invalid.
                let (xl, yu) = (x.saturating_sub(1), y.saturating_sub(1));
                let step = [
                    (xl, y),
                    ((x + 1).min(w - 1), y),
                    (x, yu),
                    (x, (y + 1).min(h - 1)),
                ]
                .iter()
                .map(|&(a, b)| {
                    let j = b * w + a;
                    if m[j] == 0.0 {
                        0.08
                    } else {
                        (s[j] - s[i]).abs()
                    }
                })
                .fold(0.0f32, f32::max);
                let edge = ((step - 0.015) / 0.03).clamp(0.0, 1.0);
                let (wf, ws, wh) = (n[2] * n[2], n[0] * n[0] * 2.0, n[1] * n[1] * 2.0);
                let sum = wf + ws + wh;
                let mut a = [0.0f32; 3];
                for (c, ac) in a.iter_mut().enumerate() {
                    *ac = (pal.face[c] * wf + pal.side[c] * ws + pal.flat[c] * wh) / sum;
                }
                let lambert = (n[0] * light[0] + n[1] * light[1] + n[2] * light[2]).max(0.0);
                let shade = 0.3 + 0.7 * lambert;
                let ao = (1.0 - 6.0 * (big[i] - s2[i]).max(0.0)).clamp(0.45, 1.0);
                let fog = (1.0 - s2[i]).powi(2) * 0.45;
                let dark = 1.0 - 0.75 * edge - 0.5 * (crease * 8.0).min(1.0);
                let mut col = [0.0f32; 3];
                for c in 0..3 {
                    let lit = a[c] * shade * ao;
                    col[c] = (lit * (1.0 - fog) + pal.fog[c] * fog) * dark.max(0.1);
                }
                col
            };
            for ch in 0..3 {
                buf[3 * i + ch] = (c[ch].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            }
        }
    }
    out
}

impl DepthShadeBackend {
    /// Shade a whole depth video (deterministic: same input, same bytes).
    pub fn shade_video(&self, depth_video: &[RgbImage], prompt: &str) -> Result<Vec<RgbImage>> {
        if depth_video.is_empty() {
            return Err(Error::Invalid(format!(
                "{NAME}: the depth video has no frames"
            )));
        }
        if self.width < 8 || self.height < 8 {
            return Err(Error::Param(format!(
                "{NAME}: output size {}x{} is too small",
                self.width, self.height
            )));
        }
        if let Some((i, f)) = depth_video
            .iter()
            .enumerate()
            .find(|(_, f)| f.width() == 0 || f.height() == 0)
        {
            return Err(Error::Shape(format!(
                "{NAME}: depth frame {i} is {}x{}",
                f.width(),
                f.height()
            )));
        }
        let (pal, _) = palette(prompt);
        let (w, h) = (self.width as usize, self.height as usize);
        Ok(depth_video
            .par_iter()
            .map(|f| shade_frame(f, w, h, &pal))
            .collect())
    }
}

impl WfmBackend for DepthShadeBackend {
    fn id(&self) -> String {
        if (self.width, self.height) == (960, 704) {
            NAME.into()
        } else {
            format!("{NAME}@{}x{}", self.width, self.height)
        }
    }

    fn frame_size(&self) -> Option<(u32, u32)> {
        Some((self.width, self.height))
    }

    fn generate(&self, req: &GenerateRequest) -> Result<Generation> {
        let prompt = req.prompt.text();
        let frames = self.shade_video(&req.depth_video, &prompt)?;
        let (_, palette_hash) = palette(&prompt);
        let provenance = Provenance {
            backend: self.id(),
            model: format!(
                "{NAME}: NOT a WFM. Deterministic shading of the depth video (pseudo-normals, \
                 occlusion edges, palette from the prompt); uses no real RGB and no ground truth"
            ),
            command: None,
            prompt,
            seed: req.seed,
            params: serde_json::json!({
                "width": self.width,
                "height": self.height,
                "palette_hash": palette_hash,
                "seed": "ignored (deterministic)",
            }),
            created_unix: now_unix(),
            frame_count: frames.len(),
            warnings: vec![format!(
                "{NAME} is not a world foundation model; results with it say nothing about Cosmos"
            )],
        };
        Ok(Generation { frames, provenance })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp_frame(w: u32, h: u32, shift: u32) -> RgbImage {
        // A floor-like ramp (brighter = nearer towards the bottom) with a box in front.
        RgbImage::from_fn(w, h, |x, y| {
            let v = if (40 + shift..90 + shift).contains(&x) && (30..70).contains(&y) {
                230
            } else if y < 5 {
                0
            } else {
                (40 + y * 150 / h) as u8
            };
            image::Rgb([v, v, v])
        })
    }

    #[test]
    fn box_blur_equals_brute_force() {
        let (w, h) = (13, 9);
        let src: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32).collect();
        for r in [1, 2, 4, 12] {
            let b = box_blur(&src, w, h, r);
            for y in 0..h {
                for x in 0..w {
                    let (mut s, mut n) = (0.0f64, 0.0f64);
                    for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                        for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                            s += src[yy * w + xx] as f64;
                            n += 1.0;
                        }
                    }
                    assert!(
                        (b[y * w + x] as f64 - s / n).abs() < 1e-4,
                        "r {r} at {x},{y}"
                    );
                }
            }
        }
    }

    #[test]
    fn deterministic_and_sized() {
        let b = DepthShadeBackend::default();
        let v = vec![ramp_frame(160, 120, 0), ramp_frame(160, 120, 2)];
        let a = b.shade_video(&v, "a kitchen").unwrap();
        let c = b.shade_video(&v, "a kitchen").unwrap();
        assert_eq!(a, c);
        assert_eq!(a[0].dimensions(), (960, 704));
        // The prompt changes the palette.
        let d = b.shade_video(&v, "a snowy forest").unwrap();
        assert_ne!(a[0], d[0]);
        assert!(b.shade_video(&[], "x").is_err());
    }

    #[test]
    fn structure_shows_in_the_image() {
        let b = DepthShadeBackend {
            width: 320,
            height: 240,
        };
        let f = b
            .shade_video(&[ramp_frame(160, 120, 0)], "x")
            .unwrap()
            .remove(0);
        let lum = |x: u32, y: u32| f.get_pixel(x, y).0.iter().map(|&c| c as u32).sum::<u32>();
        // Void rows (grey 0) are dark; the box's occlusion edge is darker than its inside.
        assert!(lum(160, 2) < 90, "void {}", lum(160, 2));
        let inside = lum(130, 100);
        let edge = (76..84).map(|x| lum(x, 100)).min().unwrap();
        assert!(edge + 60 < inside, "edge {edge} inside {inside}");
        // Nearby frames give similar images (consistent appearance under small motion).
        let g = b
            .shade_video(&[ramp_frame(160, 120, 1)], "x")
            .unwrap()
            .remove(0);
        let q = crate::wfm::video::psnr(&f, &g).unwrap();
        assert!(q > 18.0, "psnr between neighbouring frames {q}");
    }
}
