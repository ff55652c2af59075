//! The GL path: the programs, the uploaded buffers and the offscreen target, kept per GL
//! context in a thread-local; `paint` draws one [`SceneFrame`].

use std::cell::RefCell;
use std::sync::Arc;

use eframe::egui;
use eframe::egui_glow;
use eframe::glow::{self, HasContext};
use three_d::{
    ClearState, Context, DepthTest, DepthTexture2D, Interpolation, Program, RenderStates,
    RenderTarget, Texture2D, VertexBuffer, Viewport, Wrapping, WriteMask,
};

use super::composite::{composite_and_lines, depth_tested, Composited};
use super::cpu::{splat_points, CpuCloud, CpuTarget};
use super::shaders::{COPY_FS, EDL_FS, POINT_FS, POINT_VS, QUAD_VS};
use super::{
    is_software_renderer, scatter_order, scattered, DepthCue, Rasterizer, SceneFrame, CPU_SPLATTING,
};

thread_local! {
    static GPU: RefCell<Option<Gpu>> = const { RefCell::new(None) };
}

pub(super) struct GpuCloud {
    pub(super) id: Option<u64>,
    pub(super) positions: VertexBuffer<[f32; 3]>,
    pub(super) colors: VertexBuffer<[u8; 4]>,
    pub(super) normals: Option<VertexBuffer<[f32; 3]>>,
    pub(super) count: u32,
    /// A line set (drawn as GL_LINES, uploaded in order) rather than a cloud.
    pub(super) lines: bool,
}

impl GpuCloud {
    pub(super) fn new(ctx: &Context, lines: bool) -> Self {
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
    pub(super) fn sync(
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

/// The offscreen colour + depth target every frame's points are drawn into, then
/// composited (eye-dome lighting or a copy); kept across frames so that a still view is
/// refined in steps and, once complete, only composited.
pub(super) struct SceneTarget {
    pub(super) size: (u32, u32),
    pub(super) color: Texture2D,
    pub(super) depth: DepthTexture2D,
    /// (points key, end) of what the target holds: points [0, end) of that key's frame.
    pub(super) holds: Option<(u64, u32)>,
}

pub(super) struct Gpu {
    pub(super) gl: Arc<glow::Context>,
    pub(super) ctx: Context,
    pub(super) points: Program,
    pub(super) edl: Program,
    pub(super) copy: Program,
    pub(super) quad: VertexBuffer<[f32; 2]>,
    pub(super) scene_target: Option<SceneTarget>,
    pub(super) source: GpuCloud,
    pub(super) target: GpuCloud,
    pub(super) overlay: GpuCloud,
    pub(super) scene_lines: GpuCloud,
    /// The GL is a software rasteriser ([`Rasterizer::Auto`] splats on the CPU).
    pub(super) software: bool,
    /// Threads (bands of rows) for CPU splatting: found once, as
    /// `available_parallelism` reads the cgroup's CPU quota from files on every call.
    pub(super) splat_threads: usize,
    pub(super) cpu: Option<CpuTarget>,
    pub(super) cpu_source: CpuCloud,
    pub(super) cpu_target: CpuCloud,
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

pub(super) fn gpu_for(gl: &Arc<glow::Context>) -> Result<(), String> {
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

pub(super) fn log_once(msg: &str) {
    use std::sync::atomic::{AtomicBool, Ordering};
    static SAID: AtomicBool = AtomicBool::new(false);
    if !SAID.swap(true, Ordering::Relaxed) {
        eprintln!("cgenreg 3D view: {msg}");
    }
}

pub(super) fn mat4(a: &[f32; 16]) -> three_d::Mat4 {
    three_d::Mat4::new(
        a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9], a[10], a[11], a[12], a[13],
        a[14], a[15],
    )
}

pub(super) const IDENTITY: [f32; 16] = [
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
pub(super) fn panel_viewport(info: &egui::PaintCallbackInfo) -> Option<(Viewport, [i32; 4])> {
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

/// Uploads the clouds (when `clouds`: the GL draws the points) and line sets whose
/// generation changed.
pub(super) fn sync_buffers(gpu: &mut Gpu, ctx: &Context, frame: &SceneFrame, clouds: bool) {
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
pub(super) fn ensure_scene_target(
    target: &mut Option<SceneTarget>,
    ctx: &Context,
    size: (u32, u32),
) {
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

/// The point program with what every draw call of a frame shares.
pub(super) struct Draw<'a> {
    pub(super) prog: &'a Program,
    pub(super) gl: &'a glow::Context,
    pub(super) frame: &'a SceneFrame,
}

impl Draw<'_> {
    /// Points [from, end) of the target (when shown) and of every drawing of the source.
    pub(super) fn points(
        &self,
        source: &GpuCloud,
        target: &GpuCloud,
        range: (u32, u32),
        viewport: Viewport,
    ) {
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
    pub(super) fn overlay(&self, lines: &GpuCloud, viewport: Viewport) {
        let states = RenderStates {
            depth_test: DepthTest::Always,
            write_mask: WriteMask::COLOR,
            ..Default::default()
        };
        self.lines(lines, states, viewport);
    }

    /// A line set in the target frame.
    pub(super) fn lines(&self, lines: &GpuCloud, states: RenderStates, viewport: Viewport) {
        let identity = (&IDENTITY, [1.0; 4]);
        let n = lines.count / 2 * 2;
        self.cloud(lines, (0, n), identity, false, states, viewport);
    }

    /// Vertices [from, end) of one buffer (points; lines when `cloud` is a line set, whose
    /// range is whole segments), under (model matrix, tint), lit by its normals when `shade`.
    pub(super) fn cloud(
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
