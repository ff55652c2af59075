"""The extension module (Rust). Use the functions of :mod:`cgenreg`; these take the
settings as `cgenreg register` options (a list of strings)."""

from typing import List, Optional, Tuple

import numpy as np
import numpy.typing as npt

HAS_GUI: bool
VERSION: str

class Result:
    """One registration's result. Arrays are handed over from the library without a copy,
    made once, and every access returns the same array."""

    @property
    def target_from_source(self) -> npt.NDArray[np.float64]: ...
    @property
    def gt_target_from_source(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def correspondences(
        self,
    ) -> Tuple[npt.NDArray[np.uint32], npt.NDArray[np.uint32], npt.NDArray[np.float32]]: ...
    @property
    def inliers(self) -> npt.NDArray[np.uint64]: ...
    @property
    def source_keypoints(self) -> npt.NDArray[np.float32]: ...
    @property
    def target_keypoints(self) -> npt.NDArray[np.float32]: ...
    @property
    def rre_deg(self) -> Optional[float]: ...
    @property
    def rte_m(self) -> Optional[float]: ...
    @property
    def success(self) -> Optional[bool]: ...
    @property
    def inlier_ratio(self) -> Optional[float]: ...
    @property
    def timings(self) -> List[Tuple[str, float, str]]: ...
    @property
    def total_ms(self) -> float: ...
    @property
    def pair_id(self) -> str: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def estimator(self) -> str: ...
    def to_json(self) -> str: ...
    def params_json(self) -> str: ...

def settings(options: List[str]) -> str: ...
def read_cloud(
    path: str,
) -> Tuple[
    npt.NDArray[np.float64],
    Optional[npt.NDArray[np.float32]],
    Optional[npt.NDArray[np.uint8]],
    Optional[npt.NDArray[np.float32]],
]: ...
def write_cloud(
    path: str,
    points: npt.NDArray[np.float32],
    intensity: Optional[npt.NDArray[np.float32]] = None,
    force: bool = False,
) -> None: ...
def register_files(
    source: str, target: str, gt: Optional[str], options: List[str]
) -> Result: ...
def register_pair(manifest: str, pair: str, options: List[str]) -> Result: ...
def register_arrays(
    source: npt.NDArray[np.float32],
    target: npt.NDArray[np.float32],
    gt: Optional[npt.NDArray[np.float64]],
    options: List[str],
    source_intensity: Optional[npt.NDArray[np.float32]] = None,
    target_intensity: Optional[npt.NDArray[np.float32]] = None,
) -> Result: ...
def fpfh(
    points: npt.NDArray[np.float32], voxel: float
) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]: ...
def match_then_fuse(
    source_geo: npt.NDArray[np.float32],
    target_geo: npt.NDArray[np.float32],
    options: List[str],
    source_img: Optional[npt.NDArray[np.float32]] = None,
    source_valid: Optional[npt.NDArray[np.bool_]] = None,
    target_img: Optional[npt.NDArray[np.float32]] = None,
    target_valid: Optional[npt.NDArray[np.bool_]] = None,
) -> Tuple[npt.NDArray[np.uint32], npt.NDArray[np.uint32], npt.NDArray[np.float32]]: ...
def estimate(
    src: npt.NDArray[np.float32],
    tgt: npt.NDArray[np.float32],
    scores: Optional[npt.NDArray[np.float32]],
    options: List[str],
) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.uint64], str, Optional[str]]: ...
def load_bench(path: str) -> str: ...
def cli_main(argv: List[str]) -> int: ...
def manifest_pairs(
    manifest: str,
) -> List[Tuple[str, str, str, str, Optional[npt.NDArray[np.float64]]]]: ...
