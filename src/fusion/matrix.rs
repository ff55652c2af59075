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
    /// A zero matrix; errors when `rows * cols` overflows.
    pub fn zeros(rows: usize, cols: usize) -> Result<Self> {
        let n = checked_len(rows, cols)?;
        // Zeroed allocation: large ones come as fresh zero pages, so nothing is written here.
        let data = vec![0.0f32; n];
        advise_huge(&data);
        Ok(DenseMatrix { rows, cols, data })
    }

    /// A copy whose buffer may use huge pages (see [`big_vec`]); `clone` does not.
    pub fn duplicate(&self) -> Self {
        let mut data = big_vec(self.data.len());
        data.extend_from_slice(&self.data);
        DenseMatrix {
            rows: self.rows,
            cols: self.cols,
            data,
        }
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

/// An empty Vec with room for `n` values. On Linux a large buffer is advised to use
/// transparent huge pages: first-touch page faults on 4 KiB pages cost about as much as the
/// softmax itself on a 100 MB matrix.
pub(crate) fn big_vec(n: usize) -> Vec<f32> {
    let mut v = Vec::with_capacity(n);
    advise_huge(v.spare_capacity_mut());
    v
}

/// Advises the kernel to back the pages inside `buf` with transparent huge pages (Linux,
/// buffers of 4 MiB or more; elsewhere nothing).
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
        assert!(check_masks("t", 3, 4, Some(&[true; 2]), None).is_err());
        assert!(check_masks("t", 3, 4, Some(&[true; 3]), Some(&[false; 4])).is_ok());
    }
}
