//! cgenreg's side of the full-size MASt3R export check (studies/mast3r-export/mast3r_full_check.sh): load an
//! export of models/export_mast3r.py and describe one image pair the way the pipeline does.
//!
//!     cargo run --release --example mast3r_describe -- MODEL.onnx DIR NAME IMG1 IMG2 [WxH]
//!     cargo run --release --example mast3r_describe -- MODEL.onnx --e2e MANIFEST PAIR_ID [FRAMES]
//!
//! With WxH both images are first resized (Catmull-Rom) to that size, as tests/it/mast3r_export.rs
//! does for 960x704 generated frames. Writes into DIR, little-endian float32:
//!   NAME.img1.f32, NAME.img2.f32                   the input tensors [3, 384, 512] in [-1, 1]
//!   NAME.img1.png, NAME.img2.png                   the RGB images described
//!   NAME.cgenreg.desc_1.f32, NAME.cgenreg.desc_2.f32   descriptors [rows, 512, 24] (padding cropped)
//! and prints the rows kept, the backend and the time of the pair. `--e2e` registers one pair of a
//! manifest with oracle RGB, this model and K = 1, no cache (tests/it/mast3r_export.rs, step 3), with
//! FRAMES depth frames per fragment (default 50, the pipeline's).

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use cgenreg::dataset::Dataset;
use cgenreg::pipeline::{ImageBranchParams, RegisterParams, Registration, VfmSpec, WfmSpec};
use cgenreg::vfm::mast3r::{self, Mast3r};
use cgenreg::vfm::PairModel;
use cgenreg::{Error, Result};
use std::path::Path;

fn write_f32(path: &Path, v: &[f32]) -> Result<()> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(path, bytes).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
}

fn open(path: &str, size: Option<(u32, u32)>) -> Result<image::RgbImage> {
    let img = image::open(path)
        .map_err(|e| Error::Invalid(format!("{path}: {e}")))?
        .to_rgb8();
    Ok(match size {
        Some((w, h)) => {
            image::imageops::resize(&img, w, h, image::imageops::FilterType::CatmullRom)
        }
        None => img,
    })
}

fn parse_size(s: &str) -> Result<(u32, u32)> {
    let bad = || Error::Invalid(format!("size {s:?}: expected WxH, e.g. 960x704"));
    let (w, h) = s.split_once('x').ok_or_else(bad)?;
    Ok((w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?))
}

/// The pair-conditioned path end to end: oracle RGB, this model, K = 1.
fn end_to_end(model: &Path, manifest: &Path, pair_id: &str, frames: usize) -> Result<()> {
    let pair = Dataset::load(manifest)?.load_pair(pair_id)?;
    let p = RegisterParams {
        image: Some(ImageBranchParams {
            backend: WfmSpec::Oracle,
            vfm: VfmSpec::Mast3r {
                model: model.to_path_buf(),
            },
            k: 1,
            frames_per_fragment: frames,
            ..Default::default()
        }),
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let r = Registration::new(&p).run(&pair)?;
    let img = r
        .image
        .as_ref()
        .ok_or_else(|| Error::Invalid("no image branch in the result".into()))?;
    println!(
        "end to end on {}: vfm {}, {} correspondences, metrics {:?}, {:.1} s",
        r.pair_id,
        img.vfm,
        r.n_correspondences,
        r.metrics,
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if (4..=5).contains(&args.len()) && args[1] == "--e2e" {
        let frames = match args.get(4) {
            Some(f) => f
                .parse()
                .map_err(|_| Error::Invalid(format!("FRAMES {f:?}: expected a count")))?,
            None => 50,
        };
        return end_to_end(Path::new(&args[0]), Path::new(&args[2]), &args[3], frames);
    }
    if !(5..=6).contains(&args.len()) {
        return Err(Error::Invalid(
            "usage: mast3r_describe MODEL.onnx DIR NAME IMG1 IMG2 [WxH]".into(),
        ));
    }
    let size = args.get(5).map(|s| parse_size(s)).transpose()?;
    let (a, b) = (open(&args[3], size)?, open(&args[4], size)?);
    let dir = Path::new(&args[1]);
    let name = &args[2];
    let t = std::time::Instant::now();
    let model = Mast3r::load(Path::new(&args[0]))?;
    println!(
        "loaded {} in {:.1} s, backend {}",
        args[0],
        t.elapsed().as_secs_f64(),
        cgenreg::vfm::backend_name()
    );
    let (pa, pb) = (mast3r::prepare(&a)?, mast3r::prepare(&b)?);
    write_f32(&dir.join(format!("{name}.img1.f32")), &pa.tensor)?;
    write_f32(&dir.join(format!("{name}.img2.f32")), &pb.tensor)?;
    for (img, which) in [(&a, "img1"), (&b, "img2")] {
        let p = dir.join(format!("{name}.{which}.png"));
        img.save(&p)
            .map_err(|e| Error::Invalid(format!("{}: {e}", p.display())))?;
    }
    let t = std::time::Instant::now();
    let (da, db) = model.describe_pair(&a, &b)?;
    println!(
        "{name}: {}x{} -> descriptors {}x{}x{} per view ({} rows of 384 are image), {:.2} s",
        a.width(),
        a.height(),
        da.height,
        da.width,
        da.dim,
        pa.resized.1,
        t.elapsed().as_secs_f64()
    );
    write_f32(&dir.join(format!("{name}.cgenreg.desc_1.f32")), &da.data)?;
    write_f32(&dir.join(format!("{name}.cgenreg.desc_2.f32")), &db.data)?;
    Ok(())
}
