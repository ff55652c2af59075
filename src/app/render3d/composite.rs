//! The offscreen points composited into egui's framebuffer (eye-dome lighting or a copy,
//! writing depth), then the lines depth-tested against them.

use eframe::glow::{self, HasContext};
use three_d::{DepthTest, RenderStates, Viewport, WriteMask};

use super::cpu::CpuTarget;
use super::gpu::{Draw, Gpu, SceneTarget};
use super::{DepthCue, SceneFrame};

/// Composites the offscreen points into the bound framebuffer (with eye-dome lighting when
/// that is the cue, else as they are), writing their depth too (so the lines drawn after
/// are depth-tested against them).
pub(super) fn composite(
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
pub(super) fn composite_and_lines(
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
pub(super) enum Composited<'a> {
    /// Drawn by the GL into its offscreen target.
    Gl(&'a SceneTarget),
    /// Splatted on the CPU and uploaded.
    Cpu(&'a CpuTarget),
}

/// Points and scene lines: depth-tested, writing colour and depth.
pub(super) fn depth_tested() -> RenderStates {
    RenderStates {
        depth_test: DepthTest::Less,
        ..Default::default()
    }
}
