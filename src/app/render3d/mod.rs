//! three-d drawing inside an egui panel.
//!
//! The panel builds a [`SceneFrame`] (plain data, `Send + Sync`) each frame and hands it to an
//! `egui_glow::CallbackFn`. The GL resources live in a thread-local keyed by the GL context,
//! because three-d objects belong to the GL thread. Point and line buffers are uploaded only
//! when their generation number changes, so a 100k-point cloud costs one draw call per frame.

pub mod camera;
pub mod nearest;

use std::cell::RefCell;
use std::sync::Arc;

use eframe::egui;
use eframe::egui_glow;
use eframe::glow::{self, HasContext};
use three_d::{
    Blend, Context, Cull, DepthTest, Mat4, Program, RenderStates, VertexBuffer, Viewport, WriteMask,
};

/// Geometry and colours of one cloud; `id` changes whenever the contents change.
#[derive(Clone)]
pub struct CloudData {
    pub id: u64,
    pub positions: Arc<Vec<[f32; 3]>>,
    pub colors: Arc<Vec<[u8; 4]>>,
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
    /// Lines drawn over the points (correspondences, highlighted match).
    pub overlay_lines: LineData,
    /// Lines drawn with depth test (camera frusta, axes).
    pub scene_lines: LineData,
    pub point_size: f32,
    pub background: [f32; 4],
}

const POINT_VS: &str = r#"
uniform mat4 mvp;
uniform float point_size;
uniform vec4 tint;
in vec3 position;
in uvec4 color;
out vec4 v_color;
void main() {
    gl_Position = mvp * vec4(position, 1.0);
    gl_PointSize = point_size;
    v_color = vec4(color) / 255.0 * tint;
}
"#;

const LINE_VS: &str = r#"
uniform mat4 mvp;
in vec3 position;
in uvec4 color;
out vec4 v_color;
void main() {
    gl_Position = mvp * vec4(position, 1.0);
    v_color = vec4(color) / 255.0;
}
"#;

const FS: &str = r#"
in vec4 v_color;
layout (location = 0) out vec4 out_color;
void main() {
    out_color = v_color;
}
"#;

struct GpuCloud {
    id: Option<u64>,
    positions: VertexBuffer<[f32; 3]>,
    colors: VertexBuffer<[u8; 4]>,
    count: u32,
}

impl GpuCloud {
    fn new(ctx: &Context) -> Self {
        Self {
            id: None,
            positions: VertexBuffer::new(ctx),
            colors: VertexBuffer::new(ctx),
            count: 0,
        }
    }
    fn sync(&mut self, id: u64, pos: &[[f32; 3]], colors: &[[u8; 4]]) {
        if self.id != Some(id) {
            let n = pos.len().min(colors.len());
            self.positions.fill(&pos[..n]);
            self.colors.fill(&colors[..n]);
            self.count = n as u32;
            self.id = Some(id);
        }
    }
}

struct Gpu {
    gl: Arc<glow::Context>,
    ctx: Context,
    points: Program,
    lines: Program,
    source: GpuCloud,
    target: GpuCloud,
    overlay: GpuCloud,
    scene_lines: GpuCloud,
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
        let ctx = Context::from_gl_context(gl.clone()).map_err(|e| format!("three-d: {e}"))?;
        let points = Program::from_source(&ctx, POINT_VS, FS).map_err(|e| format!("{e}"))?;
        let lines = Program::from_source(&ctx, LINE_VS, FS).map_err(|e| format!("{e}"))?;
        *g = Some(Gpu {
            gl: gl.clone(),
            source: GpuCloud::new(&ctx),
            target: GpuCloud::new(&ctx),
            overlay: GpuCloud::new(&ctx),
            scene_lines: GpuCloud::new(&ctx),
            ctx,
            points,
            lines,
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

fn mat4(m: &[f32; 16]) -> Mat4 {
    Mat4::new(
        m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], m[12], m[13],
        m[14], m[15],
    )
}

/// Draws one frame into the currently bound framebuffer, inside the callback's viewport.
pub fn paint(
    info: &egui::PaintCallbackInfo,
    gl: &Arc<glow::Context>,
    frame: &SceneFrame,
) -> Result<(), String> {
    gpu_for(gl)?;
    let vp = info.viewport_in_pixels();
    let clip = info.clip_rect_in_pixels();
    // Clear only where the panel is visible, or the heading above it is wiped.
    let x0 = vp.left_px.max(clip.left_px);
    let y0 = vp.from_bottom_px.max(clip.from_bottom_px);
    let x1 = (vp.left_px + vp.width_px).min(clip.left_px + clip.width_px);
    let y1 = (vp.from_bottom_px + vp.height_px).min(clip.from_bottom_px + clip.height_px);
    if x1 <= x0 || y1 <= y0 {
        return Ok(());
    }
    GPU.with(|g| {
        let mut g = g.borrow_mut();
        let Some(gpu) = g.as_mut() else {
            return Err("no GL state".to_string());
        };
        unsafe {
            gl.disable(glow::FRAMEBUFFER_SRGB);
            gl.enable(glow::SCISSOR_TEST);
            gl.scissor(x0, y0, x1 - x0, y1 - y0);
            let b = frame.background;
            gl.clear_color(b[0], b[1], b[2], b[3]);
            gl.depth_mask(true);
            gl.clear(glow::COLOR_BUFFER_BIT | glow::DEPTH_BUFFER_BIT);
            gl.enable(glow::PROGRAM_POINT_SIZE);
        }
        let viewport = Viewport {
            x: vp.left_px,
            y: vp.from_bottom_px,
            width: vp.width_px as u32,
            height: vp.height_px as u32,
        };
        let vp_m = mat4(&frame.view_proj);
        let states = RenderStates {
            depth_test: DepthTest::Less,
            write_mask: WriteMask::COLOR_AND_DEPTH,
            blend: Blend::Disabled,
            cull: Cull::None,
        };
        gpu.source.sync(
            frame.source.id,
            &frame.source.positions,
            &frame.source.colors,
        );
        gpu.target.sync(
            frame.target.id,
            &frame.target.positions,
            &frame.target.colors,
        );
        gpu.overlay.sync(
            frame.overlay_lines.id,
            &frame.overlay_lines.positions,
            &frame.overlay_lines.colors,
        );
        gpu.scene_lines.sync(
            frame.scene_lines.id,
            &frame.scene_lines.positions,
            &frame.scene_lines.colors,
        );
        let draw_points = |prog: &Program, cloud: &GpuCloud, model: Mat4, tint: [f32; 4]| {
            if cloud.count == 0 {
                return;
            }
            prog.use_uniform("mvp", vp_m * model);
            prog.use_uniform("point_size", frame.point_size);
            prog.use_uniform(
                "tint",
                three_d::Vec4::new(tint[0], tint[1], tint[2], tint[3]),
            );
            prog.use_vertex_attribute("position", &cloud.positions);
            prog.use_vertex_attribute("color", &cloud.colors);
            let n = cloud.count as i32;
            prog.draw_with(states, viewport, || unsafe {
                gl.draw_arrays(glow::POINTS, 0, n);
            });
        };
        let ident = mat4(&[
            1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.,
        ]);
        if frame.show_target {
            draw_points(&gpu.points, &gpu.target, ident, [1.0; 4]);
        }
        for inst in &frame.source_instances {
            draw_points(&gpu.points, &gpu.source, mat4(&inst.model), inst.tint);
        }
        let draw_lines = |prog: &Program, lines: &GpuCloud, states: RenderStates| {
            if lines.count < 2 {
                return;
            }
            prog.use_uniform("mvp", vp_m);
            prog.use_vertex_attribute("position", &lines.positions);
            prog.use_vertex_attribute("color", &lines.colors);
            let n = (lines.count / 2 * 2) as i32;
            prog.draw_with(states, viewport, || unsafe {
                gl.draw_arrays(glow::LINES, 0, n);
            });
        };
        draw_lines(&gpu.lines, &gpu.scene_lines, states);
        draw_lines(
            &gpu.lines,
            &gpu.overlay,
            RenderStates {
                depth_test: DepthTest::Always,
                ..states
            },
        );
        let _ = &gpu.ctx;
        unsafe {
            gl.disable(glow::PROGRAM_POINT_SIZE);
        }
        Ok(())
    })
}
