//! Dense row-major `rows x cols` f32 matrices for similarities and posteriors.
//!
//! Layout: entry (i, j) (source point i, target point j) is `data[i * cols + j]`. Validity is
//! never stored as an N x M boolean matrix: in the image branch entry (i, j) is valid iff
//! source point i and target point j both have a pixel (reference §8.1), so a row-validity and
//! a column-validity vector (`Option<&[bool]>`, `None` = all valid) describe it exactly.

use crate::{Error, Result};

/// A dense row-major f32 matrix.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DenseMatrix {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f32>,
}

impl DenseMatrix {
    /// A zero matrix; errors when `rows * cols` overflows, when the matrix is above the
    /// dense-matrix budget ([`budget_bytes`]) or when the memory cannot be had (never an
    /// abort).
    pub fn zeros(rows: usize, cols: usize) -> Result<Self> {
        let n = checked_len(rows, cols)?;
        within_budget(rows, cols)?;
        // Zeroed allocation: large ones come as fresh zero pages, so nothing is written here.
        // One out-of-memory error for the whole crate (Python raises MemoryError for it).
        let what = format!("a {rows} x {cols} matrix ({})", gib(n * 4));
        let need = (n as u64).saturating_mul(4);
        crate::io::limits::check_memory(&what, need)?;
        let data = zeroed_vec(n).ok_or_else(|| Error::OutOfMemory {
            what,
            need,
            available: crate::io::limits::memory_headroom().unwrap_or(0),
        })?;
        advise_huge(&data);
        Ok(DenseMatrix { rows, cols, data })
    }

    /// A copy whose buffer may use huge pages (see [`advise_huge`]); `clone` does not. Errors as
    /// [`Self::zeros`].
    pub fn duplicate(&self) -> Result<Self> {
        within_budget(self.rows, self.cols)?;
        let mut data = Vec::new();
        if data.try_reserve_exact(self.data.len()).is_err() {
            return Err(Error::OutOfMemory {
                what: format!(
                    "a copy of a {} x {} matrix ({})",
                    self.rows,
                    self.cols,
                    gib(self.bytes())
                ),
                need: self.bytes() as u64,
                available: crate::io::limits::memory_headroom().unwrap_or(0),
            });
        }
        advise_huge(data.spare_capacity_mut());
        data.extend_from_slice(&self.data);
        Ok(DenseMatrix {
            rows: self.rows,
            cols: self.cols,
            data,
        })
    }

    /// Wraps `data` (row-major); errors when its length is not `rows * cols`.
    pub fn from_vec(rows: usize, cols: usize, data: Vec<f32>) -> Result<Self> {
        let n = checked_len(rows, cols)?;
        if data.len() != n {
            return Err(Error::Shape(format!(
                "matrix data: expected {rows} x {cols} = {n} values, found {}",
                data.len()
            )));
        }
        Ok(DenseMatrix { rows, cols, data })
    }

    /// Builds a matrix from a function of (row, column).
    pub fn from_fn(
        rows: usize,
        cols: usize,
        mut f: impl FnMut(usize, usize) -> f32,
    ) -> Result<Self> {
        let n = checked_len(rows, cols)?;
        within_budget(rows, cols)?;
        let mut data = Vec::with_capacity(n);
        for i in 0..rows {
            for j in 0..cols {
                data.push(f(i, j));
            }
        }
        Ok(DenseMatrix { rows, cols, data })
    }

    /// Heap bytes held by the values.
    pub fn bytes(&self) -> usize {
        self.data.len() * std::mem::size_of::<f32>()
    }

    pub fn shape(&self) -> (usize, usize) {
        (self.rows, self.cols)
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Entry (i, j). Panics when out of range, like slice indexing; see [`Self::try_get`].
    pub fn get(&self, i: usize, j: usize) -> f32 {
        assert!(
            i < self.rows && j < self.cols,
            "index ({i}, {j}) out of {} x {}",
            self.rows,
            self.cols
        );
        self.data[i * self.cols + j]
    }

    /// Entry (i, j), or None when out of range.
    pub fn try_get(&self, i: usize, j: usize) -> Option<f32> {
        (i < self.rows && j < self.cols).then(|| self.data[i * self.cols + j])
    }

    /// Row i (the scores of source point i against every target point).
    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.cols..(i + 1) * self.cols]
    }

    pub fn row_mut(&mut self, i: usize) -> &mut [f32] {
        &mut self.data[i * self.cols..(i + 1) * self.cols]
    }

    /// Column j copied out (columns are strided).
    pub fn column(&self, j: usize) -> Vec<f32> {
        (0..self.rows)
            .map(|i| self.data[i * self.cols + j])
            .collect()
    }

    pub fn rows_iter(&self) -> impl Iterator<Item = &[f32]> {
        self.data.chunks(self.cols.max(1)).take(self.rows)
    }
}

/// The dense-matrix budget when `CGENREG_MATRIX_BUDGET_MB` is not set: 2 GiB per N x M f32
/// matrix (2^29 entries, e.g. 23k x 23k keypoints). The pipeline streams larger pairs band by
/// band where its configuration allows ([`crate::fusion::streams_from_features`]); what needs
/// whole matrices (other fusion configurations, the inspector's kept similarities, the
/// correspondence export) stops with an error naming the sizes instead.
pub const DEFAULT_BUDGET_BYTES: usize = 2 << 30;

/// Bytes one N x M matrix may hold: `CGENREG_MATRIX_BUDGET_MB` (MiB) when set to a number,
/// else [`DEFAULT_BUDGET_BYTES`]. At most a few such matrices are held at once (a fusion holds
/// the two similarities, the two posteriors and the fused scores).
pub fn budget_bytes() -> usize {
    std::env::var("CGENREG_MATRIX_BUDGET_MB")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .map_or(DEFAULT_BUDGET_BYTES, |mb| mb.saturating_mul(1 << 20))
}

/// Whether a `rows x cols` f32 matrix fits [`budget_bytes`]; the error names the sizes and
/// the setting.
pub fn within_budget(rows: usize, cols: usize) -> Result<()> {
    let bytes = rows.saturating_mul(cols).saturating_mul(4);
    let budget = budget_bytes();
    if bytes > budget {
        return Err(Error::Invalid(format!(
            "a dense {rows} x {cols} matrix ({}) is above the dense-matrix budget of {} \
             (set CGENREG_MATRIX_BUDGET_MB to change it, or use a larger voxel for fewer \
             keypoints); geometry alone and the default Noisy-AND stream without it",
            gib(bytes),
            gib(budget)
        )));
    }
    Ok(())
}

fn gib(bytes: usize) -> String {
    format!("{:.2} GiB", bytes as f64 / (1u64 << 30) as f64)
}

/// `n` zeros from the allocator's zeroed allocation (fresh pages, nothing written), or None
/// when the memory cannot be had.
fn zeroed_vec(n: usize) -> Option<Vec<f32>> {
    if n == 0 {
        return Some(Vec::new());
    }
    let layout = std::alloc::Layout::array::<f32>(n).ok()?;
    // SAFETY: the layout has a non-zero size (n > 0).
    let p = unsafe { std::alloc::alloc_zeroed(layout) }.cast::<f32>();
    if p.is_null() {
        return None;
    }
    // SAFETY: p comes from the global allocator with the layout of n f32 (capacity n), and all
    // n values are initialised (zero bits are 0.0).
    Some(unsafe { Vec::from_raw_parts(p, n, n) })
}

/// Advises the kernel to back the pages inside `buf` with transparent huge pages (Linux,
/// buffers of 4 MiB or more; elsewhere nothing): first-touch page faults on 4 KiB pages cost
/// about as much as the softmax itself on a 100 MB matrix.
fn advise_huge<T>(buf: &[T]) {
    #[cfg(target_os = "linux")]
    {
        let (addr, len) = (buf.as_ptr() as usize, std::mem::size_of_val(buf));
        let start = (addr + 4095) & !4095;
        let end = (addr + len) & !4095;
        if len >= 4 << 20 && end > start {
            // SAFETY: advice on pages inside our own allocation; it changes no contents and a
            // failure is harmless.
            unsafe {
                libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = buf;
}

fn checked_len(rows: usize, cols: usize) -> Result<usize> {
    rows.checked_mul(cols)
        .filter(|n| n.checked_mul(4).is_some())
        .ok_or_else(|| Error::Invalid(format!("matrix {rows} x {cols} is too large")))
}

/// Checks that optional row/column validity vectors fit a `rows x cols` matrix.
pub fn check_masks(
    what: &str,
    rows: usize,
    cols: usize,
    row_valid: Option<&[bool]>,
    col_valid: Option<&[bool]>,
) -> Result<()> {
    if let Some(r) = row_valid {
        if r.len() != rows {
            return Err(Error::Shape(format!(
                "{what}: row validity has {} entries, the matrix has {rows} rows",
                r.len()
            )));
        }
    }
    if let Some(c) = col_valid {
        if c.len() != cols {
            return Err(Error::Shape(format!(
                "{what}: column validity has {} entries, the matrix has {cols} columns",
                c.len()
            )));
        }
    }
    Ok(())
}

/// Rows per parallel task so that each task touches roughly `target` entries.
pub(crate) fn rows_per_task(rows: usize, cols: usize, target: usize) -> usize {
    (target / cols.max(1)).clamp(1, rows.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_and_accessors() {
        let m = DenseMatrix::from_fn(3, 4, |i, j| (i * 10 + j) as f32).unwrap();
        assert_eq!(m.bytes(), 48);
        assert_eq!(m.get(2, 3), 23.0);
        assert_eq!(m.row(1), &[10.0, 11.0, 12.0, 13.0]);
        assert_eq!(m.column(2), vec![2.0, 12.0, 22.0]);
        assert_eq!(m.try_get(3, 0), None);
        assert_eq!(m.rows_iter().count(), 3);
        assert!(DenseMatrix::from_vec(2, 2, vec![0.0; 3]).is_err());
        assert!(DenseMatrix::zeros(usize::MAX, 2).is_err());
        // above the budget (16 GiB; unless the environment raised it): an error naming the
        // sizes and the setting, nothing allocated
        let big = 1 << 16;
        if budget_bytes() < big * big * 4 {
            let e = DenseMatrix::zeros(big, big).unwrap_err().to_string();
            assert!(
                e.contains("65536 x 65536") && e.contains("CGENREG_MATRIX_BUDGET_MB"),
                "{e}"
            );
        }
        assert_eq!(m.duplicate().unwrap(), m);
        assert!(check_masks("t", 3, 4, Some(&[true; 2]), None).is_err());
        assert!(check_masks("t", 3, 4, Some(&[true; 3]), Some(&[false; 4])).is_ok());
    }
}
