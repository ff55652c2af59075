//! Rendering the inspector without any window system: a surfaceless EGL context (Mesa's
//! software device on machines without a GPU), an RGBA8 + DEPTH24 framebuffer, the same egui
//! UI and three-d 3D view, read back into an image.
//!
//! At run time this needs an EGL implementation with `EGL_EXT_device_enumeration` and
//! `EGL_KHR_surfaceless_context` (Debian: libegl1, libegl-mesa0, libgl1-mesa-dri, libgles2).
//! Without one, every entry point returns an error saying so; nothing panics.

use std::path::Path;
use std::sync::Arc;

use eframe::egui;
use eframe::egui_glow;
use eframe::glow::{self, HasContext};
use glutin::api::egl::{context::PossiblyCurrentContext, device::Device, display::Display};
use glutin::config::{ConfigSurfaceTypes, ConfigTemplateBuilder};
use glutin::context::{ContextApi, ContextAttributesBuilder, GlProfile, Version};
use glutin::prelude::*;

use super::model::InspectorModel;
use super::shell::App;
use super::state::Panel;

/// A current, surfaceless GL 3.3 core context with an offscreen framebuffer and an egui
/// painter. Bound to the thread that created it.
pub struct HeadlessGl {
    gl: Arc<glow::Context>,
    painter: egui_glow::Painter,
    fbo: glow::Framebuffer,
    color: glow::Renderbuffer,
    depth: glow::Renderbuffer,
    size: (u32, u32),
    /// Description of the GL implementation ("llvmpipe ...").
    pub renderer: String,
    _context: PossiblyCurrentContext,
    _display: Display,
}

fn make_context() -> Result<(Display, PossiblyCurrentContext), String> {
    let devices: Vec<Device> = Device::query_devices()
        .map_err(|e| format!("no EGL device could be enumerated ({e}); install Mesa's EGL (libegl1 libegl-mesa0 libgl1-mesa-dri)"))?
        .collect();
    if devices.is_empty() {
        return Err("EGL reports no rendering device; install Mesa's EGL (libegl1 libegl-mesa0 libgl1-mesa-dri)".into());
    }
    // Prefer Mesa's software device: identical pixels on every machine (snapshot tests).
    let mut order: Vec<&Device> = devices
        .iter()
        .filter(|d| d.extensions().contains("EGL_MESA_device_software"))
        .collect();
    order.extend(
        devices
            .iter()
            .filter(|d| !d.extensions().contains("EGL_MESA_device_software")),
    );
    if let Ok(want) = std::env::var("CGENREG_EGL_DEVICE") {
        if want == "hardware" {
            order.reverse();
        }
    }
    let mut errors = Vec::new();
    for dev in order {
        match try_device(dev) {
            Ok(x) => return Ok(x),
            Err(e) => errors.push(e),
        }
    }
    Err(format!(
        "no EGL device gave a surfaceless GL 3.3 context: {}",
        errors.join("; ")
    ))
}

fn try_device(dev: &Device) -> Result<(Display, PossiblyCurrentContext), String> {
    // SAFETY: no native display handle is passed; glutin owns the EGL display.
    let display = unsafe { Display::with_device(dev, None) }
        .map_err(|e| format!("eglGetPlatformDisplay: {e}"))?;
    let templates = [
        ConfigTemplateBuilder::new()
            .with_surface_type(ConfigSurfaceTypes::empty())
            .build(),
        ConfigTemplateBuilder::new()
            .with_surface_type(ConfigSurfaceTypes::PBUFFER)
            .build(),
    ];
    let mut config = None;
    for t in templates {
        // SAFETY: the template names no native window.
        if let Ok(mut it) = unsafe { display.find_configs(t) } {
            if let Some(c) = it.next() {
                config = Some(c);
                break;
            }
        }
    }
    let config = config.ok_or("no EGL config")?;
    let attrs = ContextAttributesBuilder::new()
        .with_context_api(ContextApi::OpenGl(Some(Version::new(3, 3))))
        .with_profile(GlProfile::Core)
        .build(None);
    // SAFETY: the config comes from this display.
    let ctx = unsafe { display.create_context(&config, &attrs) }
        .map_err(|e| format!("eglCreateContext: {e}"))?;
    let ctx = ctx
        .make_current_surfaceless()
        .map_err(|e| format!("eglMakeCurrent (surfaceless): {e}"))?;
    Ok((display, ctx))
}

impl HeadlessGl {
    pub fn new(size: (u32, u32)) -> Result<Self, String> {
        let (display, context) = make_context()?;
        // SAFETY: the context is current on this thread; the loader returns its symbols.
        let gl = unsafe {
            glow::Context::from_loader_function_cstr(|s| display.get_proc_address(s) as *const _)
        };
        let gl = Arc::new(gl);
        let renderer = unsafe { gl.get_parameter_string(glow::RENDERER) };
        let (fbo, color, depth) = unsafe {
            let fbo = gl.create_framebuffer()?;
            let color = gl.create_renderbuffer()?;
            let depth = gl.create_renderbuffer()?;
            (fbo, color, depth)
        };
        let painter = egui_glow::Painter::new(gl.clone(), "", None, false)
            .map_err(|e| format!("egui painter: {e}"))?;
        let mut me = Self {
            gl,
            painter,
            fbo,
            color,
            depth,
            size: (0, 0),
            renderer,
            _context: context,
            _display: display,
        };
        me.resize(size)?;
        Ok(me)
    }

    pub fn gl(&self) -> &Arc<glow::Context> {
        &self.gl
    }

    pub fn size(&self) -> (u32, u32) {
        self.size
    }

    pub fn resize(&mut self, size: (u32, u32)) -> Result<(), String> {
        if size == self.size {
            return Ok(());
        }
        if size.0 == 0 || size.1 == 0 || size.0 > 8192 || size.1 > 8192 {
            return Err(format!(
                "screenshot size {}x{} out of range (1..=8192)",
                size.0, size.1
            ));
        }
        let gl = &self.gl;
        unsafe {
            gl.bind_renderbuffer(glow::RENDERBUFFER, Some(self.color));
            gl.renderbuffer_storage(
                glow::RENDERBUFFER,
                glow::RGBA8,
                size.0 as i32,
                size.1 as i32,
            );
            gl.bind_renderbuffer(glow::RENDERBUFFER, Some(self.depth));
            gl.renderbuffer_storage(
                glow::RENDERBUFFER,
                glow::DEPTH_COMPONENT24,
                size.0 as i32,
                size.1 as i32,
            );
            gl.bind_framebuffer(glow::FRAMEBUFFER, Some(self.fbo));
            gl.framebuffer_renderbuffer(
                glow::FRAMEBUFFER,
                glow::COLOR_ATTACHMENT0,
                glow::RENDERBUFFER,
                Some(self.color),
            );
            gl.framebuffer_renderbuffer(
                glow::FRAMEBUFFER,
                glow::DEPTH_ATTACHMENT,
                glow::RENDERBUFFER,
                Some(self.depth),
            );
            let status = gl.check_framebuffer_status(glow::FRAMEBUFFER);
            if status != glow::FRAMEBUFFER_COMPLETE {
                return Err(format!("offscreen framebuffer incomplete (0x{status:x})"));
            }
        }
        self.size = size;
        Ok(())
    }

    /// Applies texture uploads and frees.
    pub fn update_textures(&mut self, delta: &mut egui::TexturesDelta) {
        for (id, ds) in delta.set.drain() {
            for d in ds {
                self.painter.set_texture(id, &d);
            }
        }
        for id in delta.free.drain() {
            self.painter.free_texture(id);
        }
    }

    /// Paints tessellated shapes into the framebuffer. `read_back`: return the pixels
    /// (top row first); otherwise only waits for the GPU to finish (benchmarks).
    pub fn paint(
        &mut self,
        ctx: &egui::Context,
        shapes: Vec<egui::epaint::ClippedShape>,
        pixels_per_point: f32,
        read_back: bool,
    ) -> Result<Option<image::RgbaImage>, String> {
        let prims = ctx.tessellate(shapes, pixels_per_point);
        let (w, h) = self.size;
        unsafe {
            self.gl.bind_framebuffer(glow::FRAMEBUFFER, Some(self.fbo));
            self.gl.viewport(0, 0, w as i32, h as i32);
            self.gl.disable(glow::SCISSOR_TEST);
        }
        let bg = ctx
            .global_style()
            .visuals
            .panel_fill
            .to_normalized_gamma_f32();
        self.painter.clear([w, h], bg);
        self.painter
            .paint_primitives([w, h], pixels_per_point, &prims);
        unsafe {
            if !read_back {
                self.gl.finish();
                return Ok(None);
            }
            let mut buf = vec![0u8; (w * h * 4) as usize];
            self.gl
                .bind_framebuffer(glow::READ_FRAMEBUFFER, Some(self.fbo));
            self.gl.read_pixels(
                0,
                0,
                w as i32,
                h as i32,
                glow::RGBA,
                glow::UNSIGNED_BYTE,
                glow::PixelPackData::Slice(Some(&mut buf)),
            );
            let err = self.gl.get_error();
            if err != glow::NO_ERROR {
                return Err(format!("GL error 0x{err:x} while reading pixels"));
            }
            // GL rows start at the bottom
            let row = (w * 4) as usize;
            let mut flipped = vec![0u8; buf.len()];
            for y in 0..h as usize {
                flipped[y * row..(y + 1) * row]
                    .copy_from_slice(&buf[(h as usize - 1 - y) * row..(h as usize - y) * row]);
            }
            image::RgbaImage::from_raw(w, h, flipped)
                .map(Some)
                .ok_or_else(|| "pixel buffer size mismatch".into())
        }
    }
}

impl Drop for HeadlessGl {
    fn drop(&mut self) {
        super::render3d::release_gl(Some(&self.gl));
        self.painter.destroy();
        unsafe {
            self.gl.delete_framebuffer(self.fbo);
            self.gl.delete_renderbuffer(self.color);
            self.gl.delete_renderbuffer(self.depth);
        }
    }
}

/// The inspector app driven frame by frame into an offscreen framebuffer.
pub struct HeadlessRenderer {
    pub gl: HeadlessGl,
    pub ctx: egui::Context,
    pub app: App,
    time: f64,
}

impl HeadlessRenderer {
    pub fn new(model: InspectorModel, size: (u32, u32)) -> Result<Self, String> {
        let gl = HeadlessGl::new(size)?;
        let ctx = egui::Context::default();
        ctx.set_theme(egui::Theme::Dark);
        ctx.set_missing_glyph_policy(egui::MissingGlyphPolicy::Tofu);
        let mut app = App::new(model, None, None);
        app.allow_dialogs = false;
        // a screenshot keeps one frame: draw it complete
        app.set_complete_3d_frames(true);
        Ok(Self {
            gl,
            ctx,
            app,
            time: 0.0,
        })
    }

    fn input(&mut self) -> egui::RawInput {
        let (w, h) = self.gl.size();
        self.time += 1.0 / 60.0;
        let mut input = egui::RawInput {
            screen_rect: Some(egui::Rect::from_min_size(
                egui::Pos2::ZERO,
                egui::vec2(w as f32, h as f32),
            )),
            time: Some(self.time),
            ..Default::default()
        };
        input
            .viewports
            .entry(egui::ViewportId::ROOT)
            .or_default()
            .native_pixels_per_point = Some(1.0);
        input
    }

    /// Runs the UI once and paints it.
    pub fn frame(&mut self, read_back: bool) -> Result<Option<image::RgbaImage>, String> {
        let input = self.input();
        let app = &mut self.app;
        let mut out = self.ctx.run_ui(input, |ui| app.show(ui));
        self.gl.update_textures(&mut out.textures_delta);
        // Answer screenshot requests as eframe does: the callback gets this frame's pixels.
        let asked: Vec<egui::ScreenshotCallback> = out
            .viewport_output
            .get(&egui::ViewportId::ROOT)
            .map(|v| {
                v.commands
                    .iter()
                    .filter_map(|c| match c {
                        egui::ViewportCommand::Screenshot(u) => Some(u.clone()),
                        _ => None,
                    })
                    .collect()
            })
            .unwrap_or_default();
        let img = self.gl.paint(
            &self.ctx,
            out.shapes,
            out.pixels_per_point,
            read_back || !asked.is_empty(),
        )?;
        if let (false, Some(shot)) = (asked.is_empty(), img.as_ref()) {
            let image = Arc::new(egui::ColorImage::from_rgba_unmultiplied(
                [shot.width() as usize, shot.height() as usize],
                shot.as_raw(),
            ));
            for callback in asked {
                callback.complete(image.clone());
            }
        }
        Ok(if read_back { img } else { None })
    }

    /// Runs enough frames for layout and textures to settle, returns the last one.
    pub fn settled_frame(&mut self) -> Result<image::RgbaImage, String> {
        for _ in 0..3 {
            self.frame(false)?;
        }
        self.frame(true)?.ok_or_else(|| "no image".into())
    }
}

/// Renders one panel of the inspector for `model` into a PNG at `out`.
pub fn render_screenshot(
    model: &InspectorModel,
    panel: Panel,
    size: (u32, u32),
    out: &Path,
) -> Result<(), String> {
    render_screenshot_with(model, panel, size, out, |_| {})
}

/// [`render_screenshot`] with the app configured first (settings shown, colour modes, ...).
pub fn render_screenshot_with(
    model: &InspectorModel,
    panel: Panel,
    size: (u32, u32),
    out: &Path,
    configure: impl FnOnce(&mut App),
) -> Result<(), String> {
    let png = render_screenshot_png(model, panel, size, configure)?;
    crate::io::output::write_atomic(out, &png).map_err(|e| e.to_string())
}

/// One panel of the inspector for `model` as PNG bytes carrying cgenreg's marker
/// ([`crate::io::output::png_with_marker`]), for a guarded write.
pub fn render_screenshot_png(
    model: &InspectorModel,
    panel: Panel,
    size: (u32, u32),
    configure: impl FnOnce(&mut App),
) -> Result<Vec<u8>, String> {
    let mut r = HeadlessRenderer::new(model.clone(), size)?;
    r.app.ui_state.tab = panel;
    configure(&mut r.app);
    let img = r.settled_frame()?;
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| format!("encoding the screenshot: {e}"))?;
    crate::io::output::png_with_marker(png.get_ref()).map_err(|e| e.to_string())
}
