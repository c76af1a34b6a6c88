//! Many tables on one grid, stored compactly: values as `f16` (11
//! significant bits, relative error 5e-4, far below any measured NDF's
//! noise) and coverage as bits. One table per sample point; at the talk's
//! scale (640,000 points x 3,072 cells) this is 3.9 GB instead of 7.9 GB.

use half::f16;
use serde::{Deserialize, Serialize};

use super::{Coverage, NdfGrid, NdfTable};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TableSet {
    grid: NdfGrid,
    len: usize,
    values: Vec<f16>,
    /// `words_per_table` u64 words per table.
    coverage: Vec<u64>,
}

impl TableSet {
    pub fn new(grid: NdfGrid, len: usize) -> Self {
        let cells = grid.len();
        Self { grid, len, values: vec![f16::ZERO; len * cells], coverage: vec![0; len * cells.div_ceil(64)] }
    }

    pub fn grid(&self) -> NdfGrid {
        self.grid
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn words(&self) -> usize {
        self.grid.len().div_ceil(64)
    }

    pub fn bytes(&self) -> usize {
        self.values.len() * 2 + self.coverage.len() * 8
    }

    /// Table `k` as an [`NdfTable`].
    pub fn get(&self, k: usize) -> NdfTable {
        let cells = self.grid.len();
        read(self.grid, &self.values[k * cells..(k + 1) * cells], self.coverage_words(k))
    }

    /// Values of table `k` as f32, into `out`.
    pub fn values_into(&self, k: usize, out: &mut [f32]) {
        let cells = self.grid.len();
        for (o, v) in out.iter_mut().zip(&self.values[k * cells..(k + 1) * cells]) {
            *o = v.to_f32();
        }
    }

    /// Coverage words of table `k`.
    pub fn coverage_words(&self, k: usize) -> &[u64] {
        let w = self.words();
        &self.coverage[k * w..(k + 1) * w]
    }

    /// Store table `k`.
    pub fn set(&mut self, k: usize, t: &NdfTable) {
        let (cells, w) = (self.grid.len(), self.words());
        write(self.grid, &mut self.values[k * cells..(k + 1) * cells], &mut self.coverage[k * w..(k + 1) * w], t);
    }

    /// Every table in order, each to read and replace on its own: tables
    /// that change independently can change in parallel, in place.
    pub fn slots(&mut self) -> impl Iterator<Item = TableSlot<'_>> {
        let (grid, cells, w) = (self.grid, self.grid.len(), self.words());
        self.values
            .chunks_exact_mut(cells)
            .zip(self.coverage.chunks_exact_mut(w))
            .map(move |(values, coverage)| TableSlot { grid, values, coverage })
    }

    /// Raw storage (for writing to disk).
    pub fn raw(&self) -> (&[f16], &[u64]) {
        (&self.values, &self.coverage)
    }

    /// Rebuild from raw storage; `None` if the lengths do not fit the grid.
    pub fn from_raw(grid: NdfGrid, len: usize, values: Vec<f16>, coverage: Vec<u64>) -> Option<Self> {
        let cells = grid.len();
        (values.len() == len * cells && coverage.len() == len * cells.div_ceil(64)).then_some(Self {
            grid,
            len,
            values,
            coverage,
        })
    }
}

/// One table of a [`TableSet`] ([`TableSet::slots`]).
#[derive(Debug)]
pub struct TableSlot<'a> {
    grid: NdfGrid,
    values: &'a mut [f16],
    coverage: &'a mut [u64],
}

impl TableSlot<'_> {
    /// The table, as [`TableSet::get`] reads it.
    pub fn get(&self) -> NdfTable {
        read(self.grid, self.values, self.coverage)
    }

    /// Replace the table, as [`TableSet::set`] does.
    pub fn set(&mut self, t: &NdfTable) {
        write(self.grid, self.values, self.coverage, t);
    }
}

fn read(grid: NdfGrid, values: &[f16], words: &[u64]) -> NdfTable {
    let values: Vec<f32> = values.iter().map(|v| v.to_f32().max(0.0)).collect();
    let cov = Coverage::from_words(grid.len(), words);
    // Lengths match by construction and values are finite and >= 0.
    NdfTable::from_values(grid, values, cov).unwrap_or_else(|_| NdfTable::zeros(grid))
}

fn write(grid: NdfGrid, values: &mut [f16], words: &mut [u64], t: &NdfTable) {
    assert_eq!(t.grid(), grid, "table grid differs from the set's");
    for (d, s) in values.iter_mut().zip(t.values()) {
        *d = f16::from_f32(*s);
    }
    words.copy_from_slice(t.coverage().words());
}
