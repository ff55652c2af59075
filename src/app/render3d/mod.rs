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
    /// At most this many points per cloud (the camera is moving); None draws every point.
    pub point_budget: Option<u32>,
}

// Points: colours as normalised bytes (three-d bound them as integer attributes), and one VAO
// per cloud set up once at upload: a frame is a handful of GL calls and one draw per cloud.
const POINT_VS: &str = r#"
uniform mat4 mvp;
uniform vec4 tint;
uniform float point_size;
in vec3 position;
in vec4 color;
out vec4 v_color;
void main() {
    gl_Position = mvp * vec4(position, 1.0);
    gl_PointSize = point_size;
    v_color = color * tint;
}
"#;

const FS: &str = r#"
in vec4 v_color;
out vec4 out_color;
void main() {
    out_color = v_color;
}
"#;

struct GpuCloud {
    id: Option<u64>,
    vao: glow::VertexArray,
    positions: glow::Buffer,
    colors: glow::Buffer,
    count: u32,
}

impl GpuCloud {
    fn new(gl: &glow::Context, prog: &GpuProgram) -> Result<Self, String> {
        unsafe {
            let vao = gl.create_vertex_array()?;
            let positions = gl.create_buffer()?;
            let colors = gl.create_buffer()?;
            gl.bind_vertex_array(Some(vao));
            gl.bind_buffer(glow::ARRAY_BUFFER, Some(positions));
            gl.enable_vertex_attrib_array(prog.position);
            gl.vertex_attrib_pointer_f32(prog.position, 3, glow::FLOAT, false, 12, 0);
            gl.bind_buffer(glow::ARRAY_BUFFER, Some(colors));
            gl.enable_vertex_attrib_array(prog.color);
            gl.vertex_attrib_pointer_f32(prog.color, 4, glow::UNSIGNED_BYTE, true, 4, 0);
            gl.bind_vertex_array(None);
            gl.bind_buffer(glow::ARRAY_BUFFER, None);
            Ok(Self {
                id: None,
                vao,
                positions,
                colors,
                count: 0,
            })
        }
    }
    /// Uploads only when the contents' id changed.
    /// Uploads in a scattered order ([`scatter_order`]) so that any prefix of the buffer is a
    /// uniform subsample: a point budget then just draws fewer vertices. Lines keep their order.
    fn sync(&mut self, gl: &glow::Context, id: u64, pos: &[[f32; 3]], colors: &[[u8; 4]]) {
        self.sync_ordered(gl, id, pos, colors, true)
    }

    fn sync_ordered(
        &mut self,
        gl: &glow::Context,
        id: u64,
        pos: &[[f32; 3]],
        colors: &[[u8; 4]],
        scatter: bool,
    ) {
        if self.id != Some(id) {
            let n = pos.len().min(colors.len());
            let (p, c): (Vec<[f32; 3]>, Vec<[u8; 4]>) = if scatter {
                scatter_order(n).map(|i| (pos[i], colors[i])).unzip()
            } else {
                (pos[..n].to_vec(), colors[..n].to_vec())
            };
            unsafe {
                gl.bind_buffer(glow::ARRAY_BUFFER, Some(self.positions));
                gl.buffer_data_u8_slice(glow::ARRAY_BUFFER, bytemuck_f32(&p), glow::STATIC_DRAW);
                gl.bind_buffer(glow::ARRAY_BUFFER, Some(self.colors));
                gl.buffer_data_u8_slice(glow::ARRAY_BUFFER, c.as_flattened(), glow::STATIC_DRAW);
                gl.bind_buffer(glow::ARRAY_BUFFER, None);
            }
            self.count = n as u32;
            self.id = Some(id);
        }
    }
    fn delete(&self, gl: &glow::Context) {
        unsafe {
            gl.delete_vertex_array(self.vao);
            gl.delete_buffer(self.positions);
            gl.delete_buffer(self.colors);
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

fn bytemuck_f32(v: &[[f32; 3]]) -> &[u8] {
    let flat = v.as_flattened();
    // SAFETY: f32 has no padding or invalid bit patterns; the length is in bytes.
    unsafe { std::slice::from_raw_parts(flat.as_ptr() as *const u8, std::mem::size_of_val(flat)) }
}

struct GpuProgram {
    program: glow::Program,
    mvp: Option<glow::UniformLocation>,
    tint: Option<glow::UniformLocation>,
    point_size: Option<glow::UniformLocation>,
    position: u32,
    color: u32,
}

fn compile(gl: &glow::Context) -> Result<GpuProgram, String> {
    let version = egui_glow::ShaderVersion::get(gl);
    if !version.is_new_shader_interface() {
        return Err(format!(
            "the 3D view needs GLSL 1.30+/ES 3.0 (have {version:?})"
        ));
    }
    let header = format!(
        "{}\n{}",
        version.version_declaration(),
        if version.is_embedded() {
            "precision highp float;"
        } else {
            ""
        }
    );
    unsafe {
        let program = gl.create_program()?;
        let mut shaders = Vec::new();
        for (kind, src) in [(glow::VERTEX_SHADER, POINT_VS), (glow::FRAGMENT_SHADER, FS)] {
            let sh = gl.create_shader(kind)?;
            gl.shader_source(sh, &format!("{header}\n{src}"));
            gl.compile_shader(sh);
            if !gl.get_shader_compile_status(sh) {
                return Err(format!("3D shader: {}", gl.get_shader_info_log(sh)));
            }
            gl.attach_shader(program, sh);
            shaders.push(sh);
        }
        gl.bind_attrib_location(program, 0, "position");
        gl.bind_attrib_location(program, 1, "color");
        gl.link_program(program);
        for sh in shaders {
            gl.detach_shader(program, sh);
            gl.delete_shader(sh);
        }
        if !gl.get_program_link_status(program) {
            return Err(format!(
                "3D shader link: {}",
                gl.get_program_info_log(program)
            ));
        }
        Ok(GpuProgram {
            mvp: gl.get_uniform_location(program, "mvp"),
            tint: gl.get_uniform_location(program, "tint"),
            point_size: gl.get_uniform_location(program, "point_size"),
            program,
            position: 0,
            color: 1,
        })
    }
}

struct Gpu {
    gl: Arc<glow::Context>,
    prog: GpuProgram,
    source: GpuCloud,
    target: GpuCloud,
    overlay: GpuCloud,
    scene_lines: GpuCloud,
}

impl Drop for Gpu {
    fn drop(&mut self) {
        for c in [&self.source, &self.target, &self.overlay, &self.scene_lines] {
            c.delete(&self.gl);
        }
        unsafe { self.gl.delete_program(self.prog.program) };
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
        let prog = compile(gl)?;
        *g = Some(Gpu {
            gl: gl.clone(),
            source: GpuCloud::new(gl, &prog)?,
            target: GpuCloud::new(gl, &prog)?,
            overlay: GpuCloud::new(gl, &prog)?,
            scene_lines: GpuCloud::new(gl, &prog)?,
            prog,
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
        }
        let vp_m = frame.view_proj;
        let mul = |a: &[f32; 16], b: &[f32; 16]| -> [f32; 16] {
            // column-major a * b
            let mut o = [0.0f32; 16];
            for c in 0..4 {
                for r in 0..4 {
                    o[c * 4 + r] = (0..4).map(|k| a[k * 4 + r] * b[c * 4 + k]).sum();
                }
            }
            o
        };
        gpu.source.sync(
            gl,
            frame.source.id,
            &frame.source.positions,
            &frame.source.colors,
        );
        gpu.target.sync(
            gl,
            frame.target.id,
            &frame.target.positions,
            &frame.target.colors,
        );
        gpu.overlay.sync_ordered(
            gl,
            frame.overlay_lines.id,
            &frame.overlay_lines.positions,
            &frame.overlay_lines.colors,
            false,
        );
        gpu.scene_lines.sync_ordered(
            gl,
            frame.scene_lines.id,
            &frame.scene_lines.positions,
            &frame.scene_lines.colors,
            false,
        );
        let prog = &gpu.prog;
        unsafe {
            gl.viewport(vp.left_px, vp.from_bottom_px, vp.width_px, vp.height_px);
            gl.use_program(Some(prog.program));
            gl.disable(glow::BLEND);
            gl.disable(glow::CULL_FACE);
            gl.enable(glow::DEPTH_TEST);
            gl.depth_func(glow::LESS);
            gl.enable(glow::PROGRAM_POINT_SIZE);
        }
        let draw = |cloud: &GpuCloud, mode: u32, mvp: &[f32; 16], tint: [f32; 4]| {
            let n = if mode == glow::LINES {
                cloud.count / 2 * 2
            } else {
                frame
                    .point_budget
                    .map_or(cloud.count, |b| cloud.count.min(b))
            };
            if n == 0 {
                return;
            }
            unsafe {
                gl.uniform_matrix_4_f32_slice(prog.mvp.as_ref(), false, mvp);
                gl.uniform_4_f32_slice(prog.tint.as_ref(), &tint);
                gl.uniform_1_f32(prog.point_size.as_ref(), frame.point_size.clamp(1.0, 16.0));
                gl.bind_vertex_array(Some(cloud.vao));
                gl.draw_arrays(mode, 0, n as i32);
            }
        };
        if frame.show_target {
            draw(&gpu.target, glow::POINTS, &vp_m, [1.0; 4]);
        }
        for inst in &frame.source_instances {
            draw(
                &gpu.source,
                glow::POINTS,
                &mul(&vp_m, &inst.model),
                inst.tint,
            );
        }
        draw(&gpu.scene_lines, glow::LINES, &vp_m, [1.0; 4]);
        unsafe { gl.disable(glow::DEPTH_TEST) };
        draw(&gpu.overlay, glow::LINES, &vp_m, [1.0; 4]);
        unsafe {
            gl.bind_vertex_array(None);
            gl.use_program(None);
            gl.disable(glow::PROGRAM_POINT_SIZE);
        }
        Ok(())
    })
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
