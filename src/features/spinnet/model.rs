//! SpinNet's network through ONNX Runtime, from an export of the authors' checkpoint made by
//! `models/spinnet_export.sh`, and the whole descriptor of a set of keypoints.
//!
//! Graph contract: input `grouped` float32 (B, voxels, 30, 3) (the output of
//! [`super::patch::grouped`]), output `descriptor` float32 (B, 32), not normalised. B is
//! dynamic.
//!
//! About 3-4 GFLOP per keypoint: keypoints go through in batches of [`BATCH`] (the first
//! layer's activations are about 55 MB per 3DMatch keypoint), with the patches of a batch
//! grouped in parallel and the network on ONNX Runtime's own threads (`CGENREG_ORT_THREADS`,
//! else every core).

use super::neighbourhood::PatchSource;
use super::{grid, patch, Protocol, DIM};
use crate::error::{Error, Result};
use crate::features::Features;
use crate::onnx::{file_id, OnnxModel};
use nalgebra::Point3;
use rayon::prelude::*;
use std::path::Path;

pub const INPUT: &str = "grouped";
pub const OUTPUT: &str = "descriptor";
/// Keypoints per network run (memory about 0.3 GB per batch for 3DMatch on the CPU).
pub const BATCH: usize = 4;

pub use super::{default_model_dir, default_model_path};

#[derive(Debug)]
pub struct SpinNet {
    model: OnnxModel,
    protocol: Protocol,
    id: String,
}

impl SpinNet {
    /// Load an export of `protocol`'s checkpoint. A missing file names the script that makes
    /// it; the input's voxel count is checked on the first run.
    pub fn load(path: &Path, protocol: Protocol) -> Result<SpinNet> {
        if !path.exists() {
            return Err(Error::format(
                path,
                "model",
                format!(
                    "a SpinNet ONNX export ({}; made by models/spinnet_export.sh from the \
                     authors' {} checkpoint)",
                    protocol.onnx_file(),
                    protocol.name()
                ),
                "no such file",
            ));
        }
        let expected = format!(
            "a SpinNet ONNX export (input `{INPUT}` [B,{},30,3], output `{OUTPUT}` [B,32])",
            protocol.geometry().voxels()
        );
        // an input like any other: a FIFO or device would block or never end the read
        crate::io::limits::check_regular(path)?;
        let model = OnnxModel::load(path, &[INPUT], &[OUTPUT], &expected)?;
        let id = format!("spinnet-{}@{}", protocol.name(), file_id(path)?);
        Ok(SpinNet {
            model,
            protocol,
            id,
        })
    }

    /// `spinnet-<protocol>@<content hash>`: what a cache key and a result's provenance name.
    pub fn id(&self) -> &str {
        &self.id
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// Descriptors of `batch` grouped patches laid end to end: (batch, 32) row-major.
    pub fn run_grouped(&self, grouped: Vec<f32>, batch: usize) -> Result<Vec<f32>> {
        let g = self.protocol.geometry();
        if grouped.len() != batch * g.grouped_len() {
            return Err(Error::Shape(format!(
                "SpinNet input holds {} floats, expected {batch} x {}",
                grouped.len(),
                g.grouped_len()
            )));
        }
        let shape = vec![batch as i64, g.voxels() as i64, g.voxel_sample as i64, 3];
        let out = self.model.run(vec![(INPUT, shape, grouped)], &[OUTPUT])?;
        let (shape, data) = &out[0];
        if shape.len() != 2 || shape[0] != batch as i64 || shape[1] != DIM as i64 {
            return Err(Error::format(
                &self.model.path,
                "output descriptor",
                format!("shape [{batch}, {DIM}]"),
                format!("{shape:?}"),
            ));
        }
        Ok(data.clone())
    }

    /// Descriptors of `keypoints` on `cloud` (patches from `cloud`, drawn with `seed`).
    pub fn describe(
        &self,
        cloud: &[Point3<f32>],
        keypoints: &[Point3<f32>],
        seed: u64,
    ) -> Result<Features> {
        let g = self.protocol.geometry();
        let centres = grid::voxel_centres(&g);
        let source = PatchSource::new(cloud, self.protocol, seed);
        let mut data = Vec::with_capacity(keypoints.len() * DIM);
        for (b, chunk) in keypoints.chunks(BATCH).enumerate() {
            let inputs: Vec<Vec<f32>> = chunk
                .par_iter()
                .enumerate()
                .map(|(j, kp)| patch::grouped(&g, &source.patch(b * BATCH + j, kp), &centres))
                .collect();
            let batch = inputs.len();
            data.extend(self.run_grouped(inputs.concat(), batch)?);
        }
        Ok(Features::new(DIM, data))
    }
}
