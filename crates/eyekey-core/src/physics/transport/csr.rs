//! Compressed-row storage with f32 values and u32 indices, and its transpose.

/// A sparse matrix in compressed-row form with f32 values and u32 indices.
#[derive(Clone, Debug, PartialEq)]
pub struct CsrMatrix {
    pub n_rows: usize,
    /// Columns.
    pub n_cols: usize,
    /// Row start offsets (n_rows + 1).
    pub indptr: Vec<u32>,
    /// Column index per entry.
    pub indices: Vec<u32>,
    /// Value per entry.
    pub values: Vec<f32>,
}

impl CsrMatrix {
    /// Stored entries.
    pub fn nnz(&self) -> usize {
        self.indices.len()
    }

    /// The transpose and, for each of its entries, the position of the same entry in `self`.
    pub(crate) fn transpose_with_map(&self) -> (CsrMatrix, Vec<u32>) {
        let nnz = self.nnz();
        let mut counts = vec![0u32; self.n_cols + 1];
        for &c in &self.indices {
            counts[c as usize + 1] += 1;
        }
        for i in 0..self.n_cols {
            counts[i + 1] += counts[i];
        }
        let indptr = counts.clone();
        let mut next = counts;
        let mut indices = vec![0u32; nnz];
        let mut values = vec![0f32; nnz];
        let mut map = vec![0u32; nnz];
        for r in 0..self.n_rows {
            for e in self.indptr[r] as usize..self.indptr[r + 1] as usize {
                let c = self.indices[e] as usize;
                let dst = next[c] as usize;
                next[c] += 1;
                indices[dst] = r as u32;
                values[dst] = self.values[e];
                map[dst] = e as u32;
            }
        }
        (
            CsrMatrix {
                n_rows: self.n_cols,
                n_cols: self.n_rows,
                indptr,
                indices,
                values,
            },
            map,
        )
    }
}
