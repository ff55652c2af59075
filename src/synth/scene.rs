//! The demo room: analytic primitives with procedural solid textures, and exact ray casting.
//!
//! World frame: metres, z up, the room spans x in [0, 5], y in [0, 4], z in [0, 2.7].

use nalgebra::{Point3, Vector3};

/// A solid (3D) procedural texture evaluated at the world hit point: view-independent, so
/// every view of a surface sees the same pattern.
#[derive(Clone, Copy, Debug)]
pub enum Texture {
    /// 3D checkerboard of cell size `cell` metres.
    Checker { cell: f64, a: [f64; 3], b: [f64; 3] },
    /// Stripes of width `width` along the world axis `axis` (0 = x, 1 = y, 2 = z).
    Stripes {
        width: f64,
        axis: usize,
        a: [f64; 3],
        b: [f64; 3],
    },
    /// Smooth value noise (two octaves) of feature size `scale`, blending `a` and `b`.
    Noise {
        scale: f64,
        a: [f64; 3],
        b: [f64; 3],
    },
    /// Random rectangles ("posters", "books") on a grid of `cell` metres, from a palette.
    Patches { cell: f64, base: [f64; 3] },
}

#[derive(Clone, Copy, Debug)]
pub enum Shape {
    /// The room: the inside of an axis-aligned box.
    Room {
        min: Point3<f64>,
        max: Point3<f64>,
    },
    /// A box of half-extents `half`, centred at `center`, rotated by `yaw` about +z.
    Box {
        center: Point3<f64>,
        half: Vector3<f64>,
        yaw: f64,
    },
    /// A vertical cylinder with its base centre at `base`.
    Cylinder {
        base: Point3<f64>,
        radius: f64,
        height: f64,
    },
    Sphere {
        center: Point3<f64>,
        radius: f64,
    },
}

#[derive(Clone, Copy, Debug)]
pub struct Object {
    pub shape: Shape,
    pub texture: Texture,
}

pub struct Hit {
    pub t: f64,
    pub normal: Vector3<f64>,
    pub object: usize,
}

/// Integer hash (splitmix64) used by the textures and the sensor noise.
pub(crate) fn hash64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E3779B97F4A7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
    z ^ (z >> 31)
}

/// Uniform in [0, 1) from a hash.
pub(crate) fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn lattice(i: i64, j: i64, k: i64, seed: u64) -> f64 {
    let h = hash64(seed ^ (i as u64).wrapping_mul(0x8CB92BA72F3D8DD7))
        ^ hash64(
            (j as u64).wrapping_mul(0x9E6C63D0676A9A99)
                ^ (k as u64).wrapping_mul(0xD6E8FEB86659FD93),
        );
    unit(hash64(h))
}

/// Trilinear value noise in [0, 1] with smoothstep interpolation.
fn value_noise(p: &Vector3<f64>, seed: u64) -> f64 {
    let f = p.map(f64::floor);
    let (i, j, k) = (f.x as i64, f.y as i64, f.z as i64);
    let w = (p - f).map(|t| t * t * (3.0 - 2.0 * t));
    let mut acc = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let wx = if dx == 1 { w.x } else { 1.0 - w.x };
                let wy = if dy == 1 { w.y } else { 1.0 - w.y };
                let wz = if dz == 1 { w.z } else { 1.0 - w.z };
                acc += wx * wy * wz * lattice(i + dx, j + dy, k + dz, seed);
            }
        }
    }
    acc
}

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [0, 1, 2].map(|c| a[c] + (b[c] - a[c]) * t)
}

const PALETTE: [[f64; 3]; 8] = [
    [0.85, 0.20, 0.15],
    [0.15, 0.45, 0.80],
    [0.95, 0.80, 0.20],
    [0.20, 0.65, 0.30],
    [0.55, 0.25, 0.65],
    [0.95, 0.55, 0.15],
    [0.10, 0.10, 0.12],
    [0.92, 0.92, 0.88],
];

impl Texture {
    /// Albedo in [0, 1] at world point `p` on a surface with normal `n` (object `id` seeds it).
    pub fn albedo(&self, p: &Point3<f64>, n: &Vector3<f64>, id: usize) -> [f64; 3] {
        // Nudge inwards so cell boundaries on a face do not flicker between views.
        let q = p.coords - n * 1e-4;
        match *self {
            Texture::Checker { cell, a, b } => {
                let s = (q / cell).map(f64::floor);
                if (s.x + s.y + s.z).rem_euclid(2.0) < 0.5 {
                    a
                } else {
                    b
                }
            }
            Texture::Stripes { width, axis, a, b } => {
                if (q[axis.min(2)] / width).floor().rem_euclid(2.0) < 0.5 {
                    a
                } else {
                    b
                }
            }
            Texture::Noise { scale, a, b } => {
                let seed = 1000 + id as u64;
                let v = 0.65 * value_noise(&(q / scale), seed)
                    + 0.35 * value_noise(&(q / (scale * 0.37)), seed + 7);
                mix(a, b, ((v - 0.5) * 2.2 + 0.5).clamp(0.0, 1.0))
            }
            Texture::Patches { cell, base } => {
                let s = (q / cell).map(f64::floor);
                let h = hash64(
                    (s.x as i64 as u64).wrapping_mul(0x9E3779B1)
                        ^ (s.y as i64 as u64).wrapping_mul(0x85EBCA77).rotate_left(21)
                        ^ (s.z as i64 as u64).wrapping_mul(0xC2B2AE3D).rotate_left(42)
                        ^ id as u64,
                );
                // A rectangle inset in each cell, in the two axes the face spans.
                let f = q / cell - s;
                let axes: [usize; 2] = match n.iamax() {
                    0 => [1, 2],
                    1 => [0, 2],
                    _ => [0, 1],
                };
                let inset = |k: usize, sh: u32| {
                    let lo = 0.08 + 0.2 * unit(hash64(h >> sh));
                    let hi = 0.92 - 0.2 * unit(hash64(h.rotate_left(sh)));
                    f[k] > lo && f[k] < hi
                };
                if !h.is_multiple_of(5) && inset(axes[0], 3) && inset(axes[1], 17) {
                    PALETTE[(h >> 7) as usize % PALETTE.len()]
                } else {
                    base
                }
            }
        }
    }
}

/// Ray (origin `o`, direction `d`, not necessarily unit) against an axis-aligned slab box;
/// returns (t, normal) of the nearest hit with t > eps, from outside or inside.
fn slab(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    lo: &Vector3<f64>,
    hi: &Vector3<f64>,
    inside: bool,
) -> Option<(f64, Vector3<f64>)> {
    let mut tmin = f64::NEG_INFINITY;
    let mut tmax = f64::INFINITY;
    let (mut amin, mut amax) = (0usize, 0usize);
    for k in 0..3 {
        if d[k].abs() < 1e-15 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[k];
        let (mut t0, mut t1) = ((lo[k] - o[k]) * inv, (hi[k] - o[k]) * inv);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > tmin {
            tmin = t0;
            amin = k;
        }
        if t1 < tmax {
            tmax = t1;
            amax = k;
        }
    }
    if tmin > tmax {
        return None;
    }
    let eps = 1e-9;
    if inside {
        // Exit point; the normal faces back into the box.
        if tmax <= eps {
            return None;
        }
        let mut n = Vector3::zeros();
        n[amax] = -d[amax].signum();
        Some((tmax, n))
    } else {
        if tmin <= eps {
            return None;
        }
        let mut n = Vector3::zeros();
        n[amin] = -d[amin].signum();
        Some((tmin, n))
    }
}

impl Shape {
    /// Nearest intersection with t > 0 of the ray o + t d.
    pub fn intersect(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
        match *self {
            Shape::Room { min, max } => slab(&o.coords, d, &min.coords, &max.coords, true),
            Shape::Box { center, half, yaw } => {
                let (s, c) = yaw.sin_cos();
                // World -> box frame is a rotation by -yaw about z.
                let to_local =
                    |v: Vector3<f64>| Vector3::new(c * v.x + s * v.y, -s * v.x + c * v.y, v.z);
                let ol = to_local(o - center);
                let dl = to_local(*d);
                let (t, nl) = slab(&ol, &dl, &(-half), &half, false)?;
                let n = Vector3::new(c * nl.x - s * nl.y, s * nl.x + c * nl.y, nl.z);
                Some((t, n))
            }
            Shape::Cylinder {
                base,
                radius,
                height,
            } => {
                let mut best: Option<(f64, Vector3<f64>)> = None;
                let (ox, oy) = (o.x - base.x, o.y - base.y);
                let a = d.x * d.x + d.y * d.y;
                if a > 1e-15 {
                    let b = 2.0 * (ox * d.x + oy * d.y);
                    let c = ox * ox + oy * oy - radius * radius;
                    let disc = b * b - 4.0 * a * c;
                    if disc >= 0.0 {
                        let t = (-b - disc.sqrt()) / (2.0 * a);
                        let z = o.z + t * d.z;
                        if t > 1e-9 && z >= base.z && z <= base.z + height {
                            let n = Vector3::new(ox + t * d.x, oy + t * d.y, 0.0) / radius;
                            best = Some((t, n));
                        }
                    }
                }
                for (zc, nz) in [(base.z + height, 1.0), (base.z, -1.0)] {
                    if d.z.abs() < 1e-15 {
                        break;
                    }
                    let t = (zc - o.z) / d.z;
                    let (x, y) = (ox + t * d.x, oy + t * d.y);
                    if t > 1e-9
                        && x * x + y * y <= radius * radius
                        && best.is_none_or(|(bt, _)| t < bt)
                        && d.z * nz < 0.0
                    {
                        best = Some((t, Vector3::new(0.0, 0.0, nz)));
                    }
                }
                best
            }
            Shape::Sphere { center, radius } => {
                let oc = o - center;
                let a = d.norm_squared();
                let b = 2.0 * oc.dot(d);
                let c = oc.norm_squared() - radius * radius;
                let disc = b * b - 4.0 * a * c;
                if disc < 0.0 {
                    return None;
                }
                let t = (-b - disc.sqrt()) / (2.0 * a);
                (t > 1e-9).then(|| (t, (oc + d * t) / radius))
            }
        }
    }
}

pub struct Scene {
    pub objects: Vec<Object>,
    /// Unit direction towards the light (directional Lambert shading).
    pub light: Vector3<f64>,
}

impl Scene {
    /// The fixed demo room: floor, walls and ceiling with distinct textures, a table, a
    /// cabinet, a shelf with "books", a sofa-like block, posters, a bin, a lamp and a ball.
    pub fn demo_room() -> Scene {
        let p = Point3::new;
        let v = Vector3::new;
        use Shape::*;
        use Texture::*;
        let objects = vec![
            // 0: room (floor/walls/ceiling share one textured box; faces differ by pattern).
            Object {
                shape: Room {
                    min: p(0.0, 0.0, 0.0),
                    max: p(5.0, 4.0, 2.7),
                },
                texture: Noise {
                    scale: 0.2,
                    a: [0.85, 0.80, 0.70],
                    b: [0.40, 0.36, 0.30],
                },
            },
            // 1: floor tiles (a thin slab on the floor).
            Object {
                shape: Box {
                    center: p(2.5, 2.0, 0.005),
                    half: v(2.5, 2.0, 0.005),
                    yaw: 0.0,
                },
                texture: Checker {
                    cell: 0.4,
                    a: [0.62, 0.58, 0.55],
                    b: [0.30, 0.27, 0.25],
                },
            },
            // 2: table top + 3: table leg (cylinder).
            Object {
                shape: Box {
                    center: p(3.6, 2.9, 0.74),
                    half: v(0.6, 0.4, 0.03),
                    yaw: 0.25,
                },
                texture: Stripes {
                    width: 0.05,
                    axis: 0,
                    a: [0.55, 0.33, 0.17],
                    b: [0.45, 0.26, 0.12],
                },
            },
            Object {
                shape: Cylinder {
                    base: p(3.6, 2.9, 0.0),
                    radius: 0.07,
                    height: 0.71,
                },
                texture: Stripes {
                    width: 0.06,
                    axis: 2,
                    a: [0.2, 0.2, 0.22],
                    b: [0.7, 0.7, 0.72],
                },
            },
            // 4: cabinet against the x = 5 wall.
            Object {
                shape: Box {
                    center: p(4.7, 1.2, 0.55),
                    half: v(0.3, 0.6, 0.55),
                    yaw: 0.0,
                },
                texture: Checker {
                    cell: 0.18,
                    a: [0.20, 0.40, 0.70],
                    b: [0.85, 0.85, 0.90],
                },
            },
            // 5: shelf with books along the y = 4 wall.
            Object {
                shape: Box {
                    center: p(1.8, 3.8, 0.9),
                    half: v(0.9, 0.2, 0.9),
                    yaw: 0.0,
                },
                texture: Patches {
                    cell: 0.12,
                    base: [0.35, 0.22, 0.12],
                },
            },
            // 6: sofa block near the y = 0 wall.
            Object {
                shape: Box {
                    center: p(2.2, 0.45, 0.3),
                    half: v(1.0, 0.4, 0.3),
                    yaw: 0.0,
                },
                texture: Noise {
                    scale: 0.08,
                    a: [0.70, 0.15, 0.20],
                    b: [0.35, 0.05, 0.10],
                },
            },
            // 7: poster on the x = 5 wall, 8: poster on the y = 4 wall, 9: poster on x = 0.
            Object {
                shape: Box {
                    center: p(4.99, 2.6, 1.6),
                    half: v(0.01, 0.6, 0.45),
                    yaw: 0.0,
                },
                texture: Patches {
                    cell: 0.2,
                    base: [0.95, 0.95, 0.92],
                },
            },
            Object {
                shape: Box {
                    center: p(3.6, 3.99, 1.7),
                    half: v(0.5, 0.01, 0.4),
                    yaw: 0.0,
                },
                texture: Noise {
                    scale: 0.05,
                    a: [0.1, 0.3, 0.6],
                    b: [0.95, 0.85, 0.3],
                },
            },
            Object {
                shape: Box {
                    center: p(0.01, 2.0, 1.5),
                    half: v(0.01, 0.7, 0.5),
                    yaw: 0.0,
                },
                texture: Checker {
                    cell: 0.1,
                    a: [0.1, 0.5, 0.2],
                    b: [0.9, 0.9, 0.3],
                },
            },
            // 10: bin, 11: lamp pole, 12: ball, 13: low box (crate) on the floor.
            Object {
                shape: Cylinder {
                    base: p(4.5, 3.5, 0.0),
                    radius: 0.18,
                    height: 0.45,
                },
                texture: Stripes {
                    width: 0.04,
                    axis: 2,
                    a: [0.9, 0.5, 0.1],
                    b: [0.2, 0.2, 0.2],
                },
            },
            Object {
                shape: Cylinder {
                    base: p(0.5, 0.5, 0.0),
                    radius: 0.03,
                    height: 1.7,
                },
                texture: Stripes {
                    width: 0.1,
                    axis: 2,
                    a: [0.8, 0.8, 0.8],
                    b: [0.3, 0.3, 0.3],
                },
            },
            Object {
                shape: Sphere {
                    center: p(1.2, 1.5, 0.25),
                    radius: 0.25,
                },
                texture: Checker {
                    cell: 0.08,
                    a: [0.9, 0.1, 0.1],
                    b: [0.95, 0.95, 0.95],
                },
            },
            Object {
                shape: Box {
                    center: p(0.6, 3.0, 0.25),
                    half: v(0.3, 0.35, 0.25),
                    yaw: -0.4,
                },
                texture: Patches {
                    cell: 0.1,
                    base: [0.6, 0.5, 0.3],
                },
            },
        ];
        Scene {
            objects,
            light: Vector3::new(0.3, 0.2, 1.0).normalize(),
        }
    }

    /// Nearest hit along o + t d (t in units of |d|).
    pub fn cast(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for (i, ob) in self.objects.iter().enumerate() {
            if let Some((t, n)) = ob.shape.intersect(o, d) {
                if best.as_ref().is_none_or(|b| t < b.t) {
                    best = Some(Hit {
                        t,
                        normal: n,
                        object: i,
                    });
                }
            }
        }
        best
    }

    /// Shaded colour in [0, 1] at a hit: albedo times ambient + Lambert.
    pub fn shade(&self, p: &Point3<f64>, hit: &Hit) -> [f64; 3] {
        let ob = &self.objects[hit.object];
        let a = ob.texture.albedo(p, &hit.normal, hit.object);
        let lam = hit.normal.dot(&self.light).max(0.0);
        let k = 0.45 + 0.55 * lam;
        a.map(|c| (c * k).clamp(0.0, 1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitives_hit_where_expected() {
        let o = Point3::new(2.5, 2.0, 1.0);
        // Room: straight down hits the floor at t = 1 with an upward normal.
        let room = Shape::Room {
            min: Point3::new(0.0, 0.0, 0.0),
            max: Point3::new(5.0, 4.0, 2.7),
        };
        let (t, n) = room.intersect(&o, &Vector3::new(0.0, 0.0, -1.0)).unwrap();
        assert!((t - 1.0).abs() < 1e-12 && n.z == 1.0);
        let (t, n) = room.intersect(&o, &Vector3::new(2.0, 0.0, 0.0)).unwrap();
        assert!((t - 1.25).abs() < 1e-12 && n.x == -1.0);
        // Rotated box: a ray along -x towards a box at x = 4 rotated 90 deg hits at its
        // y half-extent (which now lies along x).
        let b = Shape::Box {
            center: Point3::new(4.0, 2.0, 1.0),
            half: Vector3::new(0.5, 0.2, 0.3),
            yaw: std::f64::consts::FRAC_PI_2,
        };
        let (t, n) = b.intersect(&o, &Vector3::new(1.0, 0.0, 0.0)).unwrap();
        assert!((t - (1.5 - 0.2)).abs() < 1e-9, "{t}");
        assert!((n - Vector3::new(-1.0, 0.0, 0.0)).norm() < 1e-9);
        // Cylinder side and cap.
        let c = Shape::Cylinder {
            base: Point3::new(4.0, 2.0, 0.0),
            radius: 0.5,
            height: 0.8,
        };
        let (t, n) = c
            .intersect(&Point3::new(2.0, 2.0, 0.5), &Vector3::new(1.0, 0.0, 0.0))
            .unwrap();
        assert!((t - 1.5).abs() < 1e-9 && (n.x + 1.0).abs() < 1e-9);
        let (t, n) = c
            .intersect(&Point3::new(4.1, 2.0, 2.0), &Vector3::new(0.0, 0.0, -1.0))
            .unwrap();
        assert!((t - 1.2).abs() < 1e-9 && n.z == 1.0);
        assert!(c
            .intersect(&Point3::new(2.0, 2.0, 1.0), &Vector3::new(1.0, 0.0, 0.0))
            .is_none());
        let s = Shape::Sphere {
            center: Point3::new(4.0, 2.0, 1.0),
            radius: 0.5,
        };
        let (t, _) = s.intersect(&o, &Vector3::new(1.0, 0.0, 0.0)).unwrap();
        assert!((t - 1.0).abs() < 1e-9);
    }
}
