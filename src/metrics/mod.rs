//! Registration metrics as the reference computes them: RRE, RTE, inlier ratio, recall,
//! accuracy at thresholds, correspondence precision/recall.
