//! three-d drawing inside an egui panel.
//!
//! The panel builds a [`SceneFrame`] (plain data, `Send + Sync`) each frame and hands it to an
//! `egui_glow::CallbackFn`, which draws it with three-d on egui's own GL context
//! (`three_d::Context::from_gl_context`): three-d programs, vertex buffers, textures and
//! render targets. Points and lines go through `Program::draw_with` with `GL_POINTS` /
//! `GL_LINES` (three-d's own draw calls only draw triangles). The GL resources live in a
//! thread-local keyed by the GL context, because they belong to the GL thread. Buffers are
//! uploaded only when their generation number changes, so a 100k-point cloud costs one draw
//! call per frame.
//!
//! Points are drawn into an offscreen colour + depth target that is kept across frames, then
//! composited into egui's framebuffer (lines go on top, depth-tested against the points).
//! Under llvmpipe each point costs CPU, so a still view is drawn progressively: the frame
//! says which range of the (scattered) buffers to add ([`SceneFrame::draw_range`]), and once
//! the view is complete, later frames of the same view only composite.
//!
//! Depth cues ([`DepthCue`]): shading by the point normals against the view direction, or
//! eye-dome lighting (the composite darkens each pixel by how much nearer its neighbours
//! are, in log depth).
//!
//! Under a software GL (llvmpipe) the points can be splatted on the CPU instead
//! ([`Rasterizer`], `splat.rs`): the same pixels at a small part of llvmpipe's per-point
//! cost; the image is uploaded and composited as the GL target is, lines stay GL draws.

//!
//! Files: `gpu.rs` (the GL path: programs, buffers, the offscreen target, `paint`),
//! `cpu.rs` (CPU splatting's kept image and its upload) over `splat.rs` (the splatting
//! kernel), `composite.rs` (the offscreen points into egui's framebuffer, then the lines),
//! `shaders.rs` (GLSL).

mod composite;
mod cpu;
mod gpu;
mod shaders;
mod splat;

pub use gpu::{paint, paint_callback, release_gl};
pub use splat::{SplatCloud, SplatImage};

use std::sync::Arc;

use serde::{Deserialize, Serialize};

/// How depth is made visible on the points.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum,
)]
pub enum DepthCue {
    /// Flat colours.
    None,
    /// Each point lit by its surface normal (local PCA) against the view direction.
    Normals,
    /// Eye-dome lighting: silhouettes and creases darkened from the depth buffer alone.
    #[default]
    Edl,
}

impl DepthCue {
    pub const ALL: [DepthCue; 3] = [Self::None, Self::Normals, Self::Edl];
    pub fn label(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Normals => "normal shading",
            Self::Edl => "eye-dome lighting",
        }
    }
}

/// Who draws the points.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum,
)]
pub enum Rasterizer {
    /// CPU splatting when the GL is a software renderer (llvmpipe, softpipe, SwiftShader),
    /// GL points otherwise.
    #[default]
    Auto,
    /// `GL_POINTS` through the GL (a GPU draws them in parallel; llvmpipe at ~0.4 µs a point).
    Gl,
    /// Splatted on the CPU into an image that the GL composites.
    Cpu,
}

impl Rasterizer {
    pub const ALL: [Rasterizer; 3] = [Self::Auto, Self::Gl, Self::Cpu];
    pub fn label(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Gl => "GL points",
            Self::Cpu => "CPU splatting",
        }
    }
}

/// Whether this thread's last painted 3D frame splatted its points on the CPU (the UI then
/// draws a still view complete in one frame instead of refining it over several); None
/// before the first paint. Per thread: the UI and its GL paint share one thread, and
/// headless renderers on other threads do not mix in.
pub fn cpu_splatting() -> Option<bool> {
    CPU_SPLATTING.with(|c| c.get())
}

thread_local! {
    pub(super) static CPU_SPLATTING: std::cell::Cell<Option<bool>> = const { std::cell::Cell::new(None) };
}

/// A GL renderer string of a software rasteriser.
pub fn is_software_renderer(renderer: &str) -> bool {
    let r = renderer.to_ascii_lowercase();
    [
        "llvmpipe",
        "softpipe",
        "swiftshader",
        "software rasterizer",
        "swrast",
    ]
    .iter()
    .any(|s| r.contains(s))
}

/// Geometry and colours of one cloud; `id` changes whenever the contents change.
#[derive(Clone)]
pub struct CloudData {
    pub id: u64,
    pub positions: Arc<Vec<[f32; 3]>>,
    pub colors: Arc<Vec<[u8; 4]>>,
    /// Unit normals (zero where unknown), for [`DepthCue::Normals`].
    pub normals: Option<Arc<Vec<[f32; 3]>>>,
}

/// One drawing of the source cloud under an alignment.
#[derive(Clone, Copy, Debug)]
pub struct Instance {
    /// Column-major model matrix (target_from_source).
    pub model: [f32; 16],
    /// Multiplies the per-point colour.
    pub tint: [f32; 4],
}

/// Line segments (pairs of vertices) in the target frame.
#[derive(Clone, Default)]
pub struct LineData {
    pub id: u64,
    pub positions: Arc<Vec<[f32; 3]>>,
    pub colors: Arc<Vec<[u8; 4]>>,
}

/// Everything the GL callback needs for one frame.
#[derive(Clone)]
pub struct SceneFrame {
    pub source: CloudData,
    pub target: CloudData,
    pub source_instances: Vec<Instance>,
    pub show_target: bool,
    /// Column-major view-projection matrix.
    pub view_proj: [f32; 16],
    /// Camera position (normal shading) and clip planes (eye-dome lighting).
    pub eye: [f32; 3],
    pub near: f32,
    pub far: f32,
    /// Lines drawn over the points (correspondences, highlighted match).
    pub overlay_lines: LineData,
    /// Lines drawn with depth test (camera frusta, axes).
    pub scene_lines: LineData,
    pub point_size: f32,
    pub background: [f32; 4],
    /// Points `[start, end)` of each cloud's scattered buffer to draw this frame. With
    /// `start > 0` they are added to what the offscreen target holds from the frames before
    /// (progressive refinement of a still view, see [`SceneFrame::points_key`]); the GL side
    /// draws `[0, end)` afresh whenever its target does not hold exactly `[0, start)` of
    /// this key. While the camera moves `end` is the point budget.
    pub draw_range: (u32, u32),
    /// A still view: draw into the kept offscreen target (refined over frames, then only
    /// composited). False while the camera moves: points go straight into egui's
    /// framebuffer (one pass less per frame), unless eye-dome lighting needs the target.
    pub keep: bool,
    pub depth_cue: DepthCue,
    /// Eye-dome lighting strength (about 1: moderate).
    pub edl_strength: f32,
    pub rasterizer: Rasterizer,
}

impl SceneFrame {
    /// Everything that decides the points' pixels in the offscreen target: two frames with
    /// the same key draw the same points the same way, so a still view can be refined over
    /// several frames and then kept. (Line sets, eye-dome lighting strength and the clip
    /// planes only act after the points, in the composite or on top.)
    pub fn points_key(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        let bits = |v: &[f32], h: &mut std::collections::hash_map::DefaultHasher| {
            v.iter().for_each(|x| x.to_bits().hash(h))
        };
        for c in [&self.source, &self.target] {
            (c.id, c.normals.is_some(), c.positions.len()).hash(&mut h);
        }
        for inst in &self.source_instances {
            bits(&inst.model, &mut h);
            bits(&inst.tint, &mut h);
        }
        (
            self.source_instances.len(),
            self.show_target,
            self.depth_cue,
            self.rasterizer,
        )
            .hash(&mut h);
        bits(&self.view_proj, &mut h);
        if self.depth_cue == DepthCue::Normals {
            bits(&self.eye, &mut h);
        }
        bits(&[self.point_size], &mut h);
        bits(&self.background, &mut h);
        h.finish()
    }

    /// Points in the larger cloud: the end of a complete draw range.
    pub fn max_points(&self) -> u32 {
        let n = |c: &CloudData| c.positions.len().min(c.colors.len()) as u32;
        n(&self.source).max(n(&self.target))
    }
}

/// `v` in the order `order`.
pub(super) fn scattered<T: Copy>(order: &[usize], v: &[T]) -> Vec<T> {
    order.iter().map(|&i| v[i]).collect()
}

/// A permutation of 0..n, i -> i * s mod n with s near n / golden ratio and coprime with n, so
/// that every prefix is spread evenly over the input order (which for our clouds is spatially
/// coherent).
pub fn scatter_order(n: usize) -> impl Iterator<Item = usize> {
    fn gcd(a: usize, b: usize) -> usize {
        if b == 0 {
            a
        } else {
            gcd(b, a % b)
        }
    }
    let mut step = ((n as f64 * 0.618_033_988_7) as usize).max(1);
    while n > 1 && gcd(step, n) != 1 {
        step += 1;
    }
    (0..n).map(move |i| ((i as u128 * step as u128) % n.max(1) as u128) as usize)
}

#[cfg(test)]
mod tests {
    use super::scatter_order;

    #[test]
    fn scatter_order_is_a_permutation_with_even_prefixes() {
        for n in [
            0usize,
            1,
            2,
            7,
            1000,
            100_000,
            300_000,
            150_000 + 7_133,
            123_457,
        ] {
            let v: Vec<usize> = scatter_order(n).collect();
            let mut s = v.clone();
            s.sort_unstable();
            assert_eq!(s, (0..n).collect::<Vec<_>>(), "n = {n}");
            if n >= 1000 {
                // the first 10 % covers every tenth of the input about equally
                let k = n / 10;
                let mut bins = [0usize; 10];
                for &i in &v[..k] {
                    bins[i * 10 / n] += 1;
                }
                for b in bins {
                    assert!(b.abs_diff(k / 10) <= k / 50 + 2, "n = {n}: {bins:?}");
                }
            }
        }
    }
}
