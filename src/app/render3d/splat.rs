//! Point splatting on the CPU, for software GL.
//!
//! Under llvmpipe (or any software rasteriser) a `GL_POINTS` draw costs about 0.4 µs of CPU
//! per point: every point goes through the general primitive pipeline (vertex shader, wide
//! point set-up as two triangles, tile binning). This file draws the same points the way the
//! point program does (same projection, same square of `point_size` pixels centred on the
//! vertex, same depth test `Less` in draw order, same colour arithmetic) straight into a
//! colour + depth image, in a few nanoseconds a point. The GL side then uploads the image and
//! composites it as it composites its own offscreen target (eye-dome lighting included), so
//! lines and frusta stay GL draws, depth-tested against the points.
//!
//! Conventions are GL's: rows from the bottom, window depth `z_ndc * 0.5 + 0.5` in `[0, 1]`
//! (1 = far plane, the cleared value), pixel centres at half-integers.

/// A colour + depth image, rows from the bottom (as GL's textures and framebuffers).
pub struct SplatImage {
    pub width: u32,
    pub height: u32,
    pub color: Vec<[u8; 4]>,
    pub depth: Vec<f32>,
}

/// One cloud drawing: points `[from, end)` of the buffers under `model`, projected by `mvp`
/// (= view_proj * model, column-major), colour `color / 255 * tint`, lit by the normals
/// against the eye when `normals` is given (as the point shader's `shade == 1`).
pub struct SplatCloud<'a> {
    pub positions: &'a [[f32; 3]],
    pub colors: &'a [[u8; 4]],
    pub normals: Option<&'a [[f32; 3]]>,
    pub mvp: [f32; 16],
    pub model: [f32; 16],
    pub tint: [f32; 4],
    pub eye: [f32; 3],
    pub point_size: f32,
}

impl SplatImage {
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            color: vec![[0; 4]; n],
            depth: vec![1.0; n],
        }
    }

    /// Background colour (as GL rounds a clear colour to 8 bits) and far depth everywhere.
    pub fn clear(&mut self, background: [f32; 4]) {
        let c = background.map(unorm8);
        self.color.fill(c);
        self.depth.fill(1.0);
    }

    /// Draws points `[from, end)` of `cloud` over what the image holds. Rows are split into
    /// bands drawn on `threads` threads (each band projects every point and writes only its
    /// own rows, so no two threads touch the same pixel and the result does not depend on
    /// the number of threads).
    pub fn splat(&mut self, cloud: &SplatCloud<'_>, (from, end): (usize, usize), threads: usize) {
        let n = cloud.positions.len().min(cloud.colors.len());
        let normals = cloud.normals.filter(|v| v.len() >= n);
        let end = end.min(n);
        if end <= from || self.width == 0 || self.height == 0 {
            return;
        }
        let w = self.width as usize;
        let h = self.height as usize;
        let threads = threads.clamp(1, h);
        let band = h.div_ceil(threads);
        let k = Kernel::new(cloud, normals, (w, h));
        let range = from..end;
        if threads == 1 {
            k.band(range, 0, &mut self.color, &mut self.depth);
            return;
        }
        std::thread::scope(|s| {
            let bands = self
                .color
                .chunks_mut(band * w)
                .zip(self.depth.chunks_mut(band * w))
                .enumerate();
            for (i, (color, depth)) in bands {
                let (k, range) = (&k, range.clone());
                s.spawn(move || k.band(range, i * band, color, depth));
            }
        });
    }
}

/// `x.ceil() as i64` without a libm call: x86-64's baseline has no SSE4.1 `roundss`, so
/// `f32::ceil` is a function call per use, a fifth of the kernel's time. Truncation rounds
/// toward zero, which is the ceiling for negative x; positive x with a fraction goes up one.
/// Out of range and NaN saturate as `as` does (the callers clamp to the image).
#[inline(always)]
fn ceil(x: f32) -> i64 {
    let t = x as i64;
    t + ((t as f32) < x) as i64
}

/// GL's float -> normalised 8-bit conversion (round to nearest).
fn unorm8(c: f32) -> u8 {
    (c.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// What every point of one drawing shares.
struct Kernel<'a> {
    cloud: &'a SplatCloud<'a>,
    normals: Option<&'a [[f32; 3]]>,
    size: (usize, usize),
    half: f32,
    /// Colours pass through unchanged (no tint, no shading): a byte copy.
    plain: bool,
}

impl<'a> Kernel<'a> {
    fn new(
        cloud: &'a SplatCloud<'a>,
        normals: Option<&'a [[f32; 3]]>,
        size: (usize, usize),
    ) -> Self {
        Self {
            cloud,
            normals,
            size,
            half: cloud.point_size.clamp(1.0, 16.0) * 0.5,
            plain: normals.is_none() && cloud.tint == [1.0; 4],
        }
    }

    /// Points of `range` into the rows `[y0, y0 + color.len() / width)`.
    fn band(
        &self,
        range: std::ops::Range<usize>,
        y0: usize,
        color: &mut [[u8; 4]],
        depth: &mut [f32],
    ) {
        let (w, h) = self.size;
        let rows = color.len() / w;
        let (yb0, yb1) = (y0 as i64, (y0 + rows) as i64);
        // a local copy: the loop's stores cannot alias it, so it stays in registers
        let m = self.cloud.mvp;
        let half = self.half;
        let (wf, hf) = (w as f32, h as f32);
        for i in range {
            let [x, y, z] = self.cloud.positions[i];
            let cw = m[3] * x + m[7] * y + m[11] * z + m[15];
            let cz = m[2] * x + m[6] * y + m[10] * z + m[14];
            // outside the near / far planes (or behind the eye): clipped, as GL clips the vertex
            let inside = cw > 0.0 && cz >= -cw && cz <= cw; // false for NaN too
            if !inside {
                continue;
            }
            let cy = m[1] * x + m[5] * y + m[9] * z + m[13];
            let inv = 1.0 / cw;
            let yw = (cy * inv * 0.5 + 0.5) * hf;
            // the pixel rows whose centres fall in [yw - half, yw + half)
            let r0 = ceil(yw - half - 0.5).max(yb0);
            let r1 = ceil(yw + half - 0.5).min(yb1);
            if r0 >= r1 {
                continue;
            }
            let cx = m[0] * x + m[4] * y + m[8] * z + m[12];
            let xw = (cx * inv * 0.5 + 0.5) * wf;
            let c0 = ceil(xw - half - 0.5).max(0);
            let c1 = ceil(xw + half - 0.5).min(w as i64);
            if c0 >= c1 {
                continue;
            }
            let d = cz * inv * 0.5 + 0.5;
            let c = self.color(i);
            for r in r0..r1 {
                let row = (r - yb0) as usize * w;
                let (cs, ds) = (
                    &mut color[row + c0 as usize..row + c1 as usize],
                    &mut depth[row + c0 as usize..row + c1 as usize],
                );
                for (cp, dp) in cs.iter_mut().zip(ds.iter_mut()) {
                    if d < *dp {
                        *dp = d;
                        *cp = c;
                    }
                }
            }
        }
    }

    /// The point shader's colour: `vec4(color) / 255 * tint`, times `0.3 + 0.7 |n . v|` when
    /// lit (n the normal under the model's rotation, v the direction to the eye).
    fn color(&self, i: usize) -> [u8; 4] {
        let c8 = self.cloud.colors[i];
        if self.plain {
            return c8;
        }
        let t = self.cloud.tint;
        let mut c = [0.0f32; 4];
        for k in 0..4 {
            c[k] = c8[k] as f32 / 255.0 * t[k];
        }
        if let Some(nv) = self.normals {
            let m = &self.cloud.model;
            let [x, y, z] = self.cloud.positions[i];
            let wp = [
                m[0] * x + m[4] * y + m[8] * z + m[12],
                m[1] * x + m[5] * y + m[9] * z + m[13],
                m[2] * x + m[6] * y + m[10] * z + m[14],
            ];
            let [a, b, e] = nv[i];
            let n = [
                m[0] * a + m[4] * b + m[8] * e,
                m[1] * a + m[5] * b + m[9] * e,
                m[2] * a + m[6] * b + m[10] * e,
            ];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let l = if len > 1e-6 {
                let v = [
                    self.cloud.eye[0] - wp[0],
                    self.cloud.eye[1] - wp[1],
                    self.cloud.eye[2] - wp[2],
                ];
                let vl = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-30);
                ((n[0] * v[0] + n[1] * v[1] + n[2] * v[2]) / (len * vl)).abs()
            } else {
                1.0
            };
            let s = 0.3 + 0.7 * l;
            for ch in c.iter_mut().take(3) {
                *ch *= s;
            }
        }
        c.map(unorm8)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY: [f32; 16] = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];

    fn lcg(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((*seed >> 40) as f32) / (1u64 << 24) as f32
    }

    /// The brute-force reference: every pixel centre tested against every point's square.
    fn reference(cloud: &SplatCloud<'_>, w: u32, h: u32) -> SplatImage {
        let mut img = SplatImage::new(w, h);
        img.clear([0.0; 4]);
        let half = cloud.point_size.clamp(1.0, 16.0) * 0.5;
        let k = Kernel::new(cloud, cloud.normals, (w as usize, h as usize));
        for (i, p) in cloud.positions.iter().enumerate() {
            let m = &cloud.mvp;
            let clip =
                [0, 1, 2, 3].map(|r| m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]);
            let inside = clip[3] > 0.0 && clip[2].abs() <= clip[3];
            if !inside {
                continue;
            }
            let inv = 1.0 / clip[3];
            let xw = (clip[0] * inv * 0.5 + 0.5) * w as f32;
            let yw = (clip[1] * inv * 0.5 + 0.5) * h as f32;
            let d = clip[2] * inv * 0.5 + 0.5;
            for r in 0..h as usize {
                for c in 0..w as usize {
                    // pixel centre c + 0.5 in [xw - half, xw + half), likewise for rows
                    let (px, py) = (c as f32, r as f32);
                    let inside = px >= xw - half - 0.5
                        && px < xw + half - 0.5
                        && py >= yw - half - 0.5
                        && py < yw + half - 0.5;
                    let j = r * w as usize + c;
                    if inside && d < img.depth[j] {
                        img.depth[j] = d;
                        img.color[j] = k.color(i);
                    }
                }
            }
        }
        img
    }

    /// Seeded clouds under a perspective-like projection, sizes 1-5, some points behind the
    /// eye or past the planes, drawn on 1-3 threads: the same image as the brute force.
    #[test]
    fn splatting_matches_the_brute_force_on_any_number_of_threads() {
        for seed0 in 1..=12u64 {
            let mut seed = seed0;
            let n = 300;
            let positions: Vec<[f32; 3]> = (0..n)
                .map(|_| {
                    [
                        lcg(&mut seed) * 2.4 - 1.2,
                        lcg(&mut seed) * 2.4 - 1.2,
                        lcg(&mut seed) * 3.0 - 0.5,
                    ]
                })
                .collect();
            let colors: Vec<[u8; 4]> = (0..n)
                .map(|i| {
                    [
                        (i * 7 % 256) as u8,
                        (i * 13 % 256) as u8,
                        (i * 29 % 256) as u8,
                        255,
                    ]
                })
                .collect();
            let normals: Vec<[f32; 3]> = (0..n)
                .map(|_| {
                    [
                        lcg(&mut seed) - 0.5,
                        lcg(&mut seed) - 0.5,
                        lcg(&mut seed) - 0.5,
                    ]
                })
                .collect();
            // x, y as they are; w = z + 1 (a perspective divide); z_clip spans the planes
            let mut mvp = IDENTITY;
            mvp[11] = 1.0;
            mvp[15] = 1.0;
            mvp[10] = 0.9;
            mvp[14] = -0.4;
            let size = 1.0 + (seed0 % 5) as f32;
            let lit = seed0 % 2 == 0;
            let cloud = SplatCloud {
                positions: &positions,
                colors: &colors,
                normals: lit.then_some(&normals[..]),
                mvp,
                model: IDENTITY,
                tint: if seed0 % 3 == 0 {
                    [0.6, 0.8, 1.0, 1.0]
                } else {
                    [1.0; 4]
                },
                eye: [0.0, 0.0, -1.0],
                point_size: size,
            };
            let (w, h) = (37, 23);
            let want = reference(&cloud, w, h);
            for threads in 1..=3 {
                let mut img = SplatImage::new(w, h);
                img.clear([0.0; 4]);
                img.splat(&cloud, (0, n), threads);
                assert_eq!(img.depth, want.depth, "seed {seed0}, {threads} thread(s)");
                assert_eq!(img.color, want.color, "seed {seed0}, {threads} thread(s)");
            }
            // drawn in two parts, the same image (progressive refinement)
            let mut img = SplatImage::new(w, h);
            img.clear([0.0; 4]);
            img.splat(&cloud, (0, n / 3), 2);
            img.splat(&cloud, (n / 3, n), 2);
            assert_eq!(img.color, want.color, "seed {seed0}, in two parts");
        }
    }

    #[test]
    fn ceil_is_f32_ceil() {
        let mut seed = 7u64;
        let mut xs = vec![
            0.0f32, -0.0, 0.5, -0.5, 1.0, -1.0, 1e-7, -1e-7, 4095.999, -4095.999,
        ];
        xs.extend((0..10_000).map(|_| (lcg(&mut seed) - 0.5) * 1e4));
        for x in xs {
            assert_eq!(ceil(x), x.ceil() as i64, "x = {x}");
        }
        assert_eq!(ceil(f32::NAN), 0);
    }

    #[test]
    fn an_empty_image_or_range_draws_nothing() {
        let p = [[0.0f32; 3]];
        let c = [[255u8; 4]];
        let cloud = SplatCloud {
            positions: &p,
            colors: &c,
            normals: None,
            mvp: IDENTITY,
            model: IDENTITY,
            tint: [1.0; 4],
            eye: [0.0; 3],
            point_size: 2.0,
        };
        let mut img = SplatImage::new(0, 0);
        img.splat(&cloud, (0, 1), 2);
        let mut img = SplatImage::new(4, 4);
        img.clear([0.0; 4]);
        img.splat(&cloud, (1, 1), 2);
        assert!(img.depth.iter().all(|&d| d == 1.0));
        img.splat(&cloud, (0, 1), 2);
        // a 2 px point at the centre of a 4 x 4 image covers the 4 centre pixels at depth 0.5
        let hit: Vec<usize> = (0..16).filter(|&j| img.depth[j] == 0.5).collect();
        assert_eq!(hit, vec![5, 6, 9, 10]);
    }
}
