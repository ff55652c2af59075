//! Match-then-Fuse: similarities, calibration into correspondence posteriors, fusion and
//! correspondence selection.

/// One putative correspondence: source point index, target point index, and its score
/// (the fused posterior, or the single-branch posterior).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    pub src: u32,
    pub tgt: u32,
    pub score: f32,
}
