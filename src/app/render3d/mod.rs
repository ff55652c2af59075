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

mod splat;

pub use splat::{SplatCloud, SplatImage};

use std::cell::RefCell;
use std::sync::Arc;

use eframe::egui;
use eframe::egui_glow;
use eframe::glow::{self, HasContext};
use serde::{Deserialize, Serialize};
use three_d::{
    ClearState, Context, DepthTest, DepthTexture2D, Interpolation, Program, RenderStates,
    RenderTarget, Texture2D, VertexBuffer, Viewport, Wrapping, WriteMask,
};

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
    static CPU_SPLATTING: std::cell::Cell<Option<bool>> = const { std::cell::Cell::new(None) };
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

// Colours as bytes bound as integer attributes (three-d binds u8 that way), hence uvec4.
const POINT_VS: &str = r#"
uniform mat4 mvp;
uniform mat4 model;
uniform vec3 eye;
uniform vec4 tint;
uniform float point_size;
uniform int shade;
in vec3 position;
in uvec4 color;
in vec3 normal;
out vec4 v_color;
void main() {
    gl_Position = mvp * vec4(position, 1.0);
    gl_PointSize = point_size;
    vec4 c = vec4(color) / 255.0 * tint;
    if (shade == 1) {
        vec3 wp = (model * vec4(position, 1.0)).xyz;
        vec3 n = mat3(model) * normal;
        float len = length(n);
        float l = len > 1e-6 ? abs(dot(n / len, normalize(eye - wp))) : 1.0;
        c.rgb *= 0.3 + 0.7 * l;
    }
    v_color = c;
}
"#;

const POINT_FS: &str = r#"
in vec4 v_color;
out vec4 out_color;
void main() {
    out_color = v_color;
}
"#;

const QUAD_VS: &str = r#"
in vec2 corner;
out vec2 uv;
void main() {
    uv = corner * 0.5 + 0.5;
    gl_Position = vec4(corner, 0.0, 1.0);
}
"#;

// The offscreen points as they are (no depth cue, or normal shading done per point).
const COPY_FS: &str = r#"
uniform sampler2D color_tex;
uniform sampler2D depth_tex;
in vec2 uv;
out vec4 out_color;
void main() {
    out_color = vec4(texture(color_tex, uv).rgb, 1.0);
    gl_FragDepth = texture(depth_tex, uv).r;
}
"#;

// Eye-dome lighting (Boucheny 2009): the response is how much nearer, in log2 of the linear
// depth, the 8 neighbours at `radius` pixels are; background neighbours count as no nearer.
const EDL_FS: &str = r#"
uniform sampler2D color_tex;
uniform sampler2D depth_tex;
uniform vec2 texel;
uniform float near;
uniform float far;
uniform float strength;
uniform vec4 background;
in vec2 uv;
out vec4 out_color;
float logz(float d) {
    return log2(near * far / (far - d * (far - near)));
}
void main() {
    float d = texture(depth_tex, uv).r;
    if (d >= 1.0) {
        out_color = background;
        gl_FragDepth = 1.0;
        return;
    }
    float l = logz(d);
    float sum = 0.0;
    for (int i = 0; i < 8; i++) {
        float a = float(i) * 0.785398;
        vec2 o = vec2(cos(a), sin(a)) * 1.5 * texel;
        float dn = texture(depth_tex, uv + o).r;
        if (dn < 1.0) {
            sum += max(0.0, l - logz(dn));
        }
    }
    float shade = exp(-sum * 60.0 * strength);
    out_color = vec4(texture(color_tex, uv).rgb * shade, 1.0);
    gl_FragDepth = d;
}
"#;

struct GpuCloud {
    id: Option<u64>,
    positions: VertexBuffer<[f32; 3]>,
    colors: VertexBuffer<[u8; 4]>,
    normals: Option<VertexBuffer<[f32; 3]>>,
    count: u32,
    /// A line set (drawn as GL_LINES, uploaded in order) rather than a cloud.
    lines: bool,
}

impl GpuCloud {
    fn new(ctx: &Context, lines: bool) -> Self {
        Self {
            id: None,
            positions: VertexBuffer::new(ctx),
            colors: VertexBuffer::new(ctx),
            normals: None,
            count: 0,
            lines,
        }
    }

    /// Uploads only when the contents' id changed, in a scattered order ([`scatter_order`])
    /// so that any prefix of the buffer is a uniform subsample: a point budget then just
    /// draws fewer vertices. Line sets keep their order.
    fn sync(
        &mut self,
        ctx: &Context,
        id: u64,
        pos: &[[f32; 3]],
        colors: &[[u8; 4]],
        normals: Option<&[[f32; 3]]>,
    ) {
        if self.id == Some(id) {
            return;
        }
        let n = pos.len().min(colors.len());
        let normals = normals.filter(|v| v.len() >= n);
        if !self.lines {
            let order: Vec<usize> = scatter_order(n).collect();
            self.positions.fill(&scattered(&order, pos));
            self.colors.fill(&scattered(&order, colors));
            self.normals =
                normals.map(|nv| VertexBuffer::new_with_data(ctx, &scattered(&order, nv)));
        } else {
            self.positions.fill(&pos[..n]);
            self.colors.fill(&colors[..n]);
            self.normals = normals.map(|nv| VertexBuffer::new_with_data(ctx, &nv[..n]));
        }
        self.count = n as u32;
        self.id = Some(id);
    }
}

/// `v` in the order `order`.
fn scattered<T: Copy>(order: &[usize], v: &[T]) -> Vec<T> {
    order.iter().map(|&i| v[i]).collect()
}

/// A cloud's scattered copy in memory, for CPU splatting of part of a cloud (the same order
/// as the GL buffers, so a draw range means the same points either way); made when first
/// needed.
#[derive(Default)]
struct CpuCloud {
    id: Option<u64>,
    positions: Vec<[f32; 3]>,
    colors: Vec<[u8; 4]>,
    normals: Option<Vec<[f32; 3]>>,
}

impl CpuCloud {
    fn sync(&mut self, cloud: &CloudData) {
        if self.id == Some(cloud.id) {
            return;
        }
        let n = cloud.positions.len().min(cloud.colors.len());
        let order: Vec<usize> = scatter_order(n).collect();
        self.positions = scattered(&order, &cloud.positions);
        self.colors = scattered(&order, &cloud.colors);
        self.normals = cloud
            .normals
            .as_deref()
            .filter(|v| v.len() >= n)
            .map(|v| scattered(&order, v));
        self.id = Some(cloud.id);
    }
}

/// The CPU-splatted points: the image, kept across frames as the GL target is, and the two
/// textures it is uploaded into (RGBA8 colour, R32F window depth).
struct CpuTarget {
    image: SplatImage,
    color: glow::Texture,
    depth: glow::Texture,
    /// (points key, end): the image holds points [0, end) of that key's frame.
    holds: Option<(u64, u32)>,
}

impl CpuTarget {
    fn new(gl: &glow::Context, (w, h): (u32, u32)) -> Result<Self, String> {
        // glTexImage2D rather than glTexStorage2D: GL 3.0 / ES 3.0 have it (storage is 4.2)
        let make = |internal: u32, format: u32, ty: u32| -> Result<glow::Texture, String> {
            unsafe {
                let t = gl.create_texture()?;
                gl.bind_texture(glow::TEXTURE_2D, Some(t));
                let none = glow::PixelUnpackData::Slice(None);
                let (w, h) = (w as i32, h as i32);
                gl.tex_image_2d(
                    glow::TEXTURE_2D,
                    0,
                    internal as i32,
                    w,
                    h,
                    0,
                    format,
                    ty,
                    none,
                );
                for (k, v) in [
                    (glow::TEXTURE_MIN_FILTER, glow::NEAREST),
                    (glow::TEXTURE_MAG_FILTER, glow::NEAREST),
                    (glow::TEXTURE_WRAP_S, glow::CLAMP_TO_EDGE),
                    (glow::TEXTURE_WRAP_T, glow::CLAMP_TO_EDGE),
                ] {
                    gl.tex_parameter_i32(glow::TEXTURE_2D, k, v as i32);
                }
                Ok(t)
            }
        };
        Ok(Self {
            image: SplatImage::new(w, h),
            color: make(glow::RGBA8, glow::RGBA, glow::UNSIGNED_BYTE)?,
            depth: make(glow::R32F, glow::RED, glow::FLOAT)?,
            holds: None,
        })
    }

    fn size(&self) -> (u32, u32) {
        (self.image.width, self.image.height)
    }

    /// Uploads the image (rows from the bottom, as GL's textures: no flip, no copy). Rows of
    /// 4-byte texels need no padding under any `UNPACK_ALIGNMENT`, so egui's setting stays.
    fn upload(&self, gl: &glow::Context) {
        let (w, h) = (self.image.width as i32, self.image.height as i32);
        let planes: [(glow::Texture, u32, u32, &[u8]); 2] = [
            (
                self.color,
                glow::RGBA,
                glow::UNSIGNED_BYTE,
                bytemuck::cast_slice(&self.image.color),
            ),
            (
                self.depth,
                glow::RED,
                glow::FLOAT,
                bytemuck::cast_slice(&self.image.depth),
            ),
        ];
        for (tex, format, ty, data) in planes {
            let data = glow::PixelUnpackData::Slice(Some(data));
            unsafe {
                gl.bind_texture(glow::TEXTURE_2D, Some(tex));
                gl.tex_sub_image_2d(glow::TEXTURE_2D, 0, 0, 0, w, h, format, ty, data);
            }
        }
        unsafe { gl.bind_texture(glow::TEXTURE_2D, None) };
    }

    fn delete(&self, gl: &glow::Context) {
        unsafe {
            gl.delete_texture(self.color);
            gl.delete_texture(self.depth);
        }
    }
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

/// The offscreen colour + depth target every frame's points are drawn into, then
/// composited (eye-dome lighting or a copy); kept across frames so that a still view is
/// refined in steps and, once complete, only composited.
struct SceneTarget {
    size: (u32, u32),
    color: Texture2D,
    depth: DepthTexture2D,
    /// (points key, end) of what the target holds: points [0, end) of that key's frame.
    holds: Option<(u64, u32)>,
}

struct Gpu {
    gl: Arc<glow::Context>,
    ctx: Context,
    points: Program,
    edl: Program,
    copy: Program,
    quad: VertexBuffer<[f32; 2]>,
    scene_target: Option<SceneTarget>,
    source: GpuCloud,
    target: GpuCloud,
    overlay: GpuCloud,
    scene_lines: GpuCloud,
    /// The GL is a software rasteriser ([`Rasterizer::Auto`] splats on the CPU).
    software: bool,
    /// Threads (bands of rows) for CPU splatting: found once, as
    /// `available_parallelism` reads the cgroup's CPU quota from files on every call.
    splat_threads: usize,
    cpu: Option<CpuTarget>,
    cpu_source: CpuCloud,
    cpu_target: CpuCloud,
}

impl Drop for Gpu {
    // Only reached through `release_gl` (with this context current): the raw textures are
    // not three-d's, so they are freed here.
    fn drop(&mut self) {
        if let Some(c) = self.cpu.take() {
            c.delete(&self.gl);
        }
    }
}

thread_local! {
    static GPU: RefCell<Option<Gpu>> = const { RefCell::new(None) };
}

fn gpu_for(gl: &Arc<glow::Context>) -> Result<(), String> {
    GPU.with(|g| {
        let mut g = g.borrow_mut();
        if g.as_ref().is_some_and(|s| Arc::ptr_eq(&s.gl, gl)) {
            return Ok(());
        }
        // State of another (possibly destroyed) context: its ids mean nothing in the current
        // one, so deleting them here could free live objects. Leak it instead.
        if let Some(old) = g.take() {
            std::mem::forget(old);
        }
        let version = egui_glow::ShaderVersion::get(gl);
        if !version.is_new_shader_interface() {
            return Err(format!(
                "the 3D view needs GLSL 3.30+/ES 3.0 (have {version:?})"
            ));
        }
        let ctx = Context::from_gl_context(gl.clone()).map_err(|e| format!("three-d: {e}"))?;
        let points = Program::from_source(&ctx, POINT_VS, POINT_FS)
            .map_err(|e| format!("3D point shader: {e}"))?;
        let edl = Program::from_source(&ctx, QUAD_VS, EDL_FS)
            .map_err(|e| format!("3D eye-dome lighting shader: {e}"))?;
        let copy = Program::from_source(&ctx, QUAD_VS, COPY_FS)
            .map_err(|e| format!("3D composite shader: {e}"))?;
        // one triangle covering the viewport
        let quad = VertexBuffer::new_with_data(&ctx, &[[-1.0f32, -1.0], [3.0, -1.0], [-1.0, 3.0]]);
        let software = is_software_renderer(&unsafe { gl.get_parameter_string(glow::RENDERER) });
        let splat_threads = std::thread::available_parallelism().map_or(1, |n| n.get().min(8));
        *g = Some(Gpu {
            software,
            splat_threads,
            cpu: None,
            cpu_source: CpuCloud::default(),
            cpu_target: CpuCloud::default(),
            gl: gl.clone(),
            source: GpuCloud::new(&ctx, false),
            target: GpuCloud::new(&ctx, false),
            overlay: GpuCloud::new(&ctx, true),
            scene_lines: GpuCloud::new(&ctx, true),
            points,
            edl,
            copy,
            quad,
            scene_target: None,
            ctx,
        });
        Ok(())
    })
}

/// Frees the GL objects made for `gl` while its context is still current (call before
/// destroying a context). `None` frees whatever this thread holds.
pub fn release_gl(gl: Option<&Arc<glow::Context>>) {
    GPU.with(|g| {
        let mut g = g.borrow_mut();
        if g.as_ref()
            .is_some_and(|s| gl.is_none_or(|gl| Arc::ptr_eq(&s.gl, gl)))
        {
            drop(g.take());
        }
    });
}

/// Wraps a frame into an egui paint callback covering `rect`.
pub fn paint_callback(rect: egui::Rect, frame: Arc<SceneFrame>) -> egui::PaintCallback {
    egui::PaintCallback {
        rect,
        callback: Arc::new(egui_glow::CallbackFn::new(move |info, painter| {
            if let Err(e) = paint(&info, painter.gl(), &frame) {
                log_once(&e);
            }
        })),
    }
}

fn log_once(msg: &str) {
    use std::sync::atomic::{AtomicBool, Ordering};
    static SAID: AtomicBool = AtomicBool::new(false);
    if !SAID.swap(true, Ordering::Relaxed) {
        eprintln!("cgenreg 3D view: {msg}");
    }
}

fn mat4(a: &[f32; 16]) -> three_d::Mat4 {
    three_d::Mat4::new(
        a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9], a[10], a[11], a[12], a[13],
        a[14], a[15],
    )
}

const IDENTITY: [f32; 16] = [
    1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
];

/// Draws one frame into the currently bound framebuffer, inside the callback's viewport.
pub fn paint(
    info: &egui::PaintCallbackInfo,
    gl: &Arc<glow::Context>,
    frame: &SceneFrame,
) -> Result<(), String> {
    gpu_for(gl)?;
    let Some((panel_vp, [x0, y0, w, h])) = panel_viewport(info) else {
        return Ok(());
    };
    // Clear and draw only where the panel is visible, or the heading above it is wiped.
    let clip_panel = || unsafe {
        gl.enable(glow::SCISSOR_TEST);
        gl.scissor(x0, y0, w, h);
    };
    GPU.with(|g| {
        let mut g = g.borrow_mut();
        let Some(gpu) = g.as_mut() else {
            return Err("no GL state".to_string());
        };
        let ctx = gpu.ctx.clone();
        // egui's framebuffer: the window's, or the headless renderer's
        let egui_fbo = unsafe { gl.get_parameter_framebuffer(glow::DRAW_FRAMEBUFFER_BINDING) };
        unsafe {
            gl.disable(glow::FRAMEBUFFER_SRGB);
        }
        clip_panel();
        let b = frame.background;
        unsafe {
            gl.clear_color(b[0], b[1], b[2], b[3]);
            gl.depth_mask(true);
            gl.clear(glow::COLOR_BUFFER_BIT | glow::DEPTH_BUFFER_BIT);
        }
        let cpu = match frame.rasterizer {
            Rasterizer::Auto => gpu.software,
            Rasterizer::Gl => false,
            Rasterizer::Cpu => true,
        };
        CPU_SPLATTING.with(|c| c.set(Some(cpu)));
        sync_buffers(gpu, &ctx, frame, !cpu);
        if cpu {
            let size = (panel_vp.width, panel_vp.height);
            splat_points(gpu, gl, frame, size)?;
            let gpu = &*gpu;
            let Some(t) = gpu.cpu.as_ref() else {
                return Err("no CPU target".to_string());
            };
            composite_and_lines(gl, gpu, Composited::Cpu(t), frame, panel_vp);
            return Ok(());
        }
        if !frame.keep && frame.depth_cue != DepthCue::Edl {
            if let Some(t) = gpu.scene_target.as_mut() {
                t.holds = None;
            }
            let gpu = &*gpu;
            let d = Draw {
                prog: &gpu.points,
                gl,
                frame,
            };
            d.points(&gpu.source, &gpu.target, frame.draw_range, panel_vp);
            d.lines(&gpu.scene_lines, depth_tested(), panel_vp);
            d.overlay(&gpu.overlay, panel_vp);
            unsafe { gl.use_program(None) };
            return Ok(());
        }
        let size = (panel_vp.width, panel_vp.height);
        ensure_scene_target(&mut gpu.scene_target, &ctx, size);
        let Some(t) = gpu.scene_target.as_mut() else {
            return Err("no offscreen target".to_string());
        };
        // Continue the target's points only when it holds exactly [0, start) of this key;
        // otherwise (first frame, camera moved, resize, another view drew in between) start
        // again from the first point.
        let key = frame.points_key();
        let (start, end) = frame.draw_range;
        let from = match t.holds {
            Some((k, held)) if k == key && held == start => start,
            _ => 0,
        };
        {
            let rt = RenderTarget::new(t.color.as_color_target(None), t.depth.as_depth_target());
            if from == 0 {
                rt.clear(ClearState::color_and_depth(b[0], b[1], b[2], b[3], 1.0));
            }
            if end > from {
                let d = Draw {
                    prog: &gpu.points,
                    gl,
                    frame,
                };
                rt.write::<std::convert::Infallible>(|| {
                    let vp = Viewport::new_at_origo(t.size.0, t.size.1);
                    d.points(&gpu.source, &gpu.target, (from, end), vp);
                    Ok(())
                })
                .ok();
            }
        }
        t.holds = Some((key, end.max(from)));
        // back to egui's framebuffer: composite, writing the points' depth for the lines
        unsafe { gl.bind_framebuffer(glow::DRAW_FRAMEBUFFER, egui_fbo) };
        clip_panel();
        let gpu = &*gpu;
        let Some(t) = gpu.scene_target.as_ref() else {
            return Err("no offscreen target".to_string());
        };
        composite_and_lines(gl, gpu, Composited::Gl(t), frame, panel_vp);
        Ok(())
    })
}

/// The panel's viewport, and the part of it inside the clip rectangle as a scissor box
/// (x, y, width, height); None when nothing of the panel is visible.
fn panel_viewport(info: &egui::PaintCallbackInfo) -> Option<(Viewport, [i32; 4])> {
    let vp = info.viewport_in_pixels();
    let clip = info.clip_rect_in_pixels();
    let x0 = vp.left_px.max(clip.left_px);
    let y0 = vp.from_bottom_px.max(clip.from_bottom_px);
    let x1 = (vp.left_px + vp.width_px).min(clip.left_px + clip.width_px);
    let y1 = (vp.from_bottom_px + vp.height_px).min(clip.from_bottom_px + clip.height_px);
    if x1 <= x0 || y1 <= y0 || vp.width_px <= 0 || vp.height_px <= 0 {
        return None;
    }
    let panel_vp = Viewport {
        x: vp.left_px,
        y: vp.from_bottom_px,
        width: vp.width_px as u32,
        height: vp.height_px as u32,
    };
    Some((panel_vp, [x0, y0, x1 - x0, y1 - y0]))
}

/// Splats the frame's points on the CPU into the kept image (continued when it holds
/// exactly `[0, start)` of this frame's points, as the GL target is), and uploads it when it
/// changed.
fn splat_points(
    gpu: &mut Gpu,
    gl: &glow::Context,
    frame: &SceneFrame,
    size: (u32, u32),
) -> Result<(), String> {
    if gpu.cpu.as_ref().is_none_or(|t| t.size() != size) {
        if let Some(old) = gpu.cpu.take() {
            old.delete(gl);
        }
        gpu.cpu = Some(CpuTarget::new(gl, size)?);
    }
    let Some(t) = gpu.cpu.as_mut() else {
        return Err("no CPU target".to_string());
    };
    let key = frame.points_key();
    let (start, end) = frame.draw_range;
    let from = match t.holds {
        Some((k, held)) if k == key && held == start => start,
        _ => 0,
    };
    if from == 0 {
        t.image.clear(frame.background);
    }
    let threads = gpu.splat_threads;
    let vp = mat4(&frame.view_proj);
    let normals = frame.depth_cue == DepthCue::Normals;
    // A whole cloud is drawn in its own order, which for scans is spatially coherent (the
    // image's cache lines are reused from point to point); a part of it (the moving budget,
    // or the rest after one) in the scattered order of the GL buffers, so that any prefix is
    // a uniform subsample. Either way the set of points is the same.
    let mut draw = |scattered: &mut CpuCloud, data: &CloudData, model: &[f32; 16], tint| {
        let n = data.positions.len().min(data.colors.len());
        let whole = from == 0 && end as usize >= n;
        let (positions, colors, nv): (&[[f32; 3]], &[[u8; 4]], _) = if whole {
            let nv = data.normals.as_deref().map(|v| v.as_slice());
            (&data.positions[..n], &data.colors[..n], nv)
        } else {
            scattered.sync(data);
            let c = &*scattered;
            (&c.positions, &c.colors, c.normals.as_deref())
        };
        let mvp: [[f32; 4]; 4] = (vp * mat4(model)).into();
        let s = SplatCloud {
            positions,
            colors,
            normals: nv.filter(|_| normals),
            mvp: bytemuck::cast(mvp),
            model: *model,
            tint,
            eye: frame.eye,
            point_size: frame.point_size,
        };
        t.image.splat(&s, (from as usize, end as usize), threads);
    };
    if end > from {
        if frame.show_target {
            draw(&mut gpu.cpu_target, &frame.target, &IDENTITY, [1.0; 4]);
        }
        for inst in &frame.source_instances {
            draw(&mut gpu.cpu_source, &frame.source, &inst.model, inst.tint);
        }
    }
    if from == 0 || end > from {
        t.upload(gl);
    }
    t.holds = Some((key, end.max(from)));
    Ok(())
}

/// Uploads the clouds (when `clouds`: the GL draws the points) and line sets whose
/// generation changed.
fn sync_buffers(gpu: &mut Gpu, ctx: &Context, frame: &SceneFrame, clouds: bool) {
    let cloud_bufs = [
        (&mut gpu.source, &frame.source),
        (&mut gpu.target, &frame.target),
    ];
    for (buf, cloud) in cloud_bufs.into_iter().filter(|_| clouds) {
        buf.sync(
            ctx,
            cloud.id,
            &cloud.positions,
            &cloud.colors,
            cloud.normals.as_deref().map(|v| v.as_slice()),
        );
    }
    for (buf, lines) in [
        (&mut gpu.overlay, &frame.overlay_lines),
        (&mut gpu.scene_lines, &frame.scene_lines),
    ] {
        buf.sync(ctx, lines.id, &lines.positions, &lines.colors, None);
    }
}

/// The offscreen colour + depth target, made again when the panel's size changes.
fn ensure_scene_target(target: &mut Option<SceneTarget>, ctx: &Context, size: (u32, u32)) {
    if target.as_ref().is_some_and(|t| t.size == size) {
        return;
    }
    *target = Some(SceneTarget {
        size,
        color: Texture2D::new_empty::<[u8; 4]>(
            ctx,
            size.0,
            size.1,
            Interpolation::Nearest,
            Interpolation::Nearest,
            None,
            Wrapping::ClampToEdge,
            Wrapping::ClampToEdge,
        ),
        depth: DepthTexture2D::new::<f32>(
            ctx,
            size.0,
            size.1,
            Wrapping::ClampToEdge,
            Wrapping::ClampToEdge,
        ),
        holds: None,
    });
}

/// Composites the offscreen points into the bound framebuffer (with eye-dome lighting when
/// that is the cue, else as they are), writing their depth too (so the lines drawn after
/// are depth-tested against them).
fn composite(
    gl: &glow::Context,
    gpu: &Gpu,
    points: Composited<'_>,
    frame: &SceneFrame,
    panel_vp: Viewport,
) {
    let b = frame.background;
    let e = if frame.depth_cue == DepthCue::Edl {
        &gpu.edl
    } else {
        &gpu.copy
    };
    let size = match points {
        Composited::Gl(t) => {
            e.use_texture("color_tex", &t.color);
            e.use_depth_texture("depth_tex", &t.depth);
            t.size
        }
        Composited::Cpu(t) => {
            // raw GL textures: uploaded from the splatted image without three-d's
            // per-fill copy and row flip
            #[allow(deprecated)]
            {
                e.use_raw_texture("color_tex", glow::TEXTURE_2D, t.color);
                e.use_raw_texture("depth_tex", glow::TEXTURE_2D, t.depth);
            }
            t.size()
        }
    };
    e.use_uniform_if_required(
        "texel",
        three_d::vec2(1.0 / size.0 as f32, 1.0 / size.1 as f32),
    );
    e.use_uniform_if_required("near", frame.near);
    e.use_uniform_if_required("far", frame.far);
    e.use_uniform_if_required("strength", frame.edl_strength);
    e.use_uniform_if_required("background", three_d::vec4(b[0], b[1], b[2], b[3]));
    e.use_vertex_attribute("corner", &gpu.quad);
    e.draw_with(
        RenderStates {
            depth_test: DepthTest::Always,
            write_mask: WriteMask::COLOR_AND_DEPTH,
            ..Default::default()
        },
        panel_vp,
        || unsafe { gl.draw_arrays(glow::TRIANGLES, 0, 3) },
    );
}

/// The points composited into egui's (bound) framebuffer, then the scene lines depth-tested
/// against them and the overlay lines on top.
fn composite_and_lines(
    gl: &glow::Context,
    gpu: &Gpu,
    points: Composited<'_>,
    frame: &SceneFrame,
    panel_vp: Viewport,
) {
    composite(gl, gpu, points, frame, panel_vp);
    let d = Draw {
        prog: &gpu.points,
        gl,
        frame,
    };
    d.lines(&gpu.scene_lines, depth_tested(), panel_vp);
    d.overlay(&gpu.overlay, panel_vp);
    unsafe { gl.use_program(None) };
}

/// Where the points to composite are.
enum Composited<'a> {
    /// Drawn by the GL into its offscreen target.
    Gl(&'a SceneTarget),
    /// Splatted on the CPU and uploaded.
    Cpu(&'a CpuTarget),
}

/// Points and scene lines: depth-tested, writing colour and depth.
fn depth_tested() -> RenderStates {
    RenderStates {
        depth_test: DepthTest::Less,
        ..Default::default()
    }
}

/// The point program with what every draw call of a frame shares.
struct Draw<'a> {
    prog: &'a Program,
    gl: &'a glow::Context,
    frame: &'a SceneFrame,
}

impl Draw<'_> {
    /// Points [from, end) of the target (when shown) and of every drawing of the source.
    fn points(&self, source: &GpuCloud, target: &GpuCloud, range: (u32, u32), viewport: Viewport) {
        let normals = self.frame.depth_cue == DepthCue::Normals;
        unsafe { self.gl.enable(glow::PROGRAM_POINT_SIZE) };
        if self.frame.show_target {
            let identity = (&IDENTITY, [1.0; 4]);
            self.cloud(target, range, identity, normals, depth_tested(), viewport);
        }
        for inst in &self.frame.source_instances {
            let placed = (&inst.model, inst.tint);
            self.cloud(source, range, placed, normals, depth_tested(), viewport);
        }
        unsafe { self.gl.disable(glow::PROGRAM_POINT_SIZE) };
    }

    /// The overlay lines: over everything, writing no depth.
    fn overlay(&self, lines: &GpuCloud, viewport: Viewport) {
        let states = RenderStates {
            depth_test: DepthTest::Always,
            write_mask: WriteMask::COLOR,
            ..Default::default()
        };
        self.lines(lines, states, viewport);
    }

    /// A line set in the target frame.
    fn lines(&self, lines: &GpuCloud, states: RenderStates, viewport: Viewport) {
        let identity = (&IDENTITY, [1.0; 4]);
        let n = lines.count / 2 * 2;
        self.cloud(lines, (0, n), identity, false, states, viewport);
    }

    /// Vertices [from, end) of one buffer (points; lines when `cloud` is a line set, whose
    /// range is whole segments), under (model matrix, tint), lit by its normals when `shade`.
    fn cloud(
        &self,
        cloud: &GpuCloud,
        (from, end): (u32, u32),
        (model, tint): (&[f32; 16], [f32; 4]),
        shade: bool,
        states: RenderStates,
        viewport: Viewport,
    ) {
        let (prog, frame) = (self.prog, self.frame);
        let end = end.min(cloud.count);
        if end <= from {
            return;
        }
        let mode = if cloud.lines {
            glow::LINES
        } else {
            glow::POINTS
        };
        let m = mat4(model);
        prog.use_uniform("mvp", mat4(&frame.view_proj) * m);
        prog.use_uniform_if_required("model", m);
        prog.use_uniform_if_required(
            "eye",
            three_d::vec3(frame.eye[0], frame.eye[1], frame.eye[2]),
        );
        prog.use_uniform_if_required("tint", three_d::vec4(tint[0], tint[1], tint[2], tint[3]));
        prog.use_uniform_if_required("point_size", frame.point_size.clamp(1.0, 16.0));
        let with_normals = shade && cloud.normals.is_some();
        prog.use_uniform_if_required("shade", if with_normals { 1i32 } else { 0 });
        prog.use_vertex_attribute("position", &cloud.positions);
        prog.use_vertex_attribute("color", &cloud.colors);
        if let (true, Some(nb)) = (with_normals, &cloud.normals) {
            if prog.requires_attribute("normal") {
                prog.use_vertex_attribute("normal", nb);
            }
        }
        prog.draw_with(states, viewport, || unsafe {
            self.gl.draw_arrays(mode, from as i32, (end - from) as i32);
        });
    }
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
