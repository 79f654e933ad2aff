//! A fixed CSC sparsity pattern, filled by scattering values emitted in a fixed order.

use clarabel::algebra::CscMatrix;

/// A fixed CSC pattern and the map from emission order to nonzero slot (duplicates are summed).
#[derive(Debug, Clone)]
pub(super) struct Pattern {
    m: usize,
    n: usize,
    colptr: Vec<usize>,
    rowval: Vec<usize>,
    slot: Vec<usize>,
    entries: Vec<(usize, usize)>,
}

impl Pattern {
    pub(super) fn new(m: usize, n: usize, entries: &[(usize, usize, f64)]) -> Self {
        let mut keys: Vec<(usize, usize)> = entries.iter().map(|&(r, c, _)| (c, r)).collect();
        keys.sort_unstable();
        keys.dedup();
        let mut colptr = vec![0; n + 1];
        for &(c, _) in &keys {
            colptr[c + 1] += 1;
        }
        for c in 0..n {
            colptr[c + 1] += colptr[c];
        }
        let rowval = keys.iter().map(|&(_, r)| r).collect();
        let slot = entries
            .iter()
            .map(|&(r, c, _)| keys.binary_search(&(c, r)).expect("entry in pattern"))
            .collect();
        Self {
            m,
            n,
            colptr,
            rowval,
            slot,
            entries: entries.iter().map(|&(r, c, _)| (r, c)).collect(),
        }
    }

    pub(super) fn scatter(&self, entries: &[(usize, usize, f64)], nz: &mut Vec<f64>) {
        debug_assert_eq!(entries.len(), self.slot.len());
        debug_assert!(entries
            .iter()
            .zip(&self.entries)
            .all(|(&(r, c, _), &e)| (r, c) == e));
        nz.clear();
        nz.resize(self.rowval.len(), 0.0);
        for (&(_, _, v), &k) in entries.iter().zip(&self.slot) {
            nz[k] += v;
        }
    }

    /// The (row, column) of every structural nonzero, column by column.
    pub(super) fn entries(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.n).flat_map(move |c| {
            (self.colptr[c]..self.colptr[c + 1]).map(move |k| (self.rowval[k], c))
        })
    }

    /// Number of structural nonzeros.
    pub(super) fn nnz(&self) -> usize {
        self.rowval.len()
    }

    pub(super) fn matrix(&self, nz: &[f64]) -> CscMatrix<f64> {
        CscMatrix::new(
            self.m,
            self.n,
            self.colptr.clone(),
            self.rowval.clone(),
            nz.to_vec(),
        )
    }
}
