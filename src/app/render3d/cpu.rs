//! CPU splatting's side of a frame: each cloud's scattered copy in memory, the kept image
//! and its upload into two textures (the kernel is `splat.rs`).

use eframe::glow::{self, HasContext};

use super::gpu::{mat4, Gpu, IDENTITY};
use super::splat::{SplatCloud, SplatImage};
use super::{scatter_order, scattered, CloudData, DepthCue, SceneFrame};

/// A cloud's scattered copy in memory, for CPU splatting of part of a cloud (the same order
/// as the GL buffers, so a draw range means the same points either way); made when first
/// needed.
#[derive(Default)]
pub(super) struct CpuCloud {
    pub(super) id: Option<u64>,
    pub(super) positions: Vec<[f32; 3]>,
    pub(super) colors: Vec<[u8; 4]>,
    pub(super) normals: Option<Vec<[f32; 3]>>,
}

impl CpuCloud {
    pub(super) fn sync(&mut self, cloud: &CloudData) {
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
pub(super) struct CpuTarget {
    pub(super) image: SplatImage,
    pub(super) color: glow::Texture,
    pub(super) depth: glow::Texture,
    /// (points key, end): the image holds points [0, end) of that key's frame.
    pub(super) holds: Option<(u64, u32)>,
}

impl CpuTarget {
    pub(super) fn new(gl: &glow::Context, (w, h): (u32, u32)) -> Result<Self, String> {
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

    pub(super) fn size(&self) -> (u32, u32) {
        (self.image.width, self.image.height)
    }

    /// Uploads the image (rows from the bottom, as GL's textures: no flip, no copy). Rows of
    /// 4-byte texels need no padding under any `UNPACK_ALIGNMENT`, so egui's setting stays.
    pub(super) fn upload(&self, gl: &glow::Context) {
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

    pub(super) fn delete(&self, gl: &glow::Context) {
        unsafe {
            gl.delete_texture(self.color);
            gl.delete_texture(self.depth);
        }
    }
}

/// Splats the frame's points on the CPU into the kept image (continued when it holds
/// exactly `[0, start)` of this frame's points, as the GL target is), and uploads it when it
/// changed.
pub(super) fn splat_points(
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
