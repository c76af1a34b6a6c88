//! Many tables on one grid, stored compactly: values as `f16` (11
//! significant bits, relative error 5e-4, far below any measured NDF's
//! noise) and coverage as bits. One table per sample point; at the talk's
//! scale (640,000 points x 3,072 cells) this is 3.9 GB instead of 7.9 GB.

use half::f16;
use half::slice::HalfFloatSliceExt;
use half::vec::HalfBitsVecExt;
use serde::{Deserialize, Serialize};

use super::{Coverage, NdfGrid, NdfTable, bit};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TableSet {
    grid: NdfGrid,
    len: usize,
    values: Vec<f16>,
    /// `words_per_table` u64 words per table.
    coverage: Vec<u64>,
}

impl TableSet {
    /// `len` empty tables (every value +0, nothing covered). The memory is
    /// asked of the system zeroed, so a table never written takes none: a
    /// refit of a quarter of the points holds only the pages their tables
    /// are on (about a third of the set, at 6 KB tables on 4 KB pages).
    pub fn new(grid: NdfGrid, len: usize) -> Self {
        let cells = grid.len();
        let values: Vec<u16> = vec![0; len * cells];
        Self { grid, len, values: values.reinterpret_into(), coverage: vec![0; len * cells.div_ceil(64)] }
    }

    /// Whether table `k` is as [`TableSet::new`] makes it (every value +0,
    /// nothing covered).
    pub fn is_blank(&self, k: usize) -> bool {
        let cells = self.grid.len();
        self.values[k * cells..(k + 1) * cells].iter().all(|v| v.to_bits() == 0)
            && self.coverage_words(k).iter().all(|&w| w == 0)
    }

    /// The same set as `clone` makes, writing only the tables that are not
    /// blank ([`TableSet::new`]: a blank one takes no memory).
    pub fn clone_written(&self) -> TableSet {
        let mut out = TableSet::new(self.grid, self.len);
        for k in (0..self.len).filter(|&k| !self.is_blank(k)) {
            out.copy_from(k, self);
        }
        out
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

    /// Values of table `k` as f32, into `out` (one value per cell of the
    /// grid), as [`TableSet::get`] reads them.
    pub fn values_into(&self, k: usize, out: &mut [f32]) {
        let cells = self.grid.len();
        read_values(&self.values[k * cells..(k + 1) * cells], out);
    }

    /// Table `k`'s value at each cell as [`TableSet::get`] reads it, one
    /// cell at a time (for readers of a few cells); `None` where `get`
    /// reads the table as all zero.
    pub fn cells(&self, k: usize) -> Option<impl Fn(usize) -> f32 + '_> {
        let cells = self.grid.len();
        let values = &self.values[k * cells..(k + 1) * cells];
        readable(values).then_some(move |c: usize| value(values[c]))
    }

    /// Coverage words of table `k`.
    pub fn coverage_words(&self, k: usize) -> &[u64] {
        let w = self.words();
        &self.coverage[k * w..(k + 1) * w]
    }

    /// The cells table `k` covers as [`TableSet::get`] reads it: none where
    /// it reads as all zero.
    pub fn covered_cells(&self, k: usize) -> usize {
        match self.cells(k) {
            Some(_) => Coverage::from_words(self.grid.len(), self.coverage_words(k)).count(),
            None => 0,
        }
    }

    /// Store table `k`.
    pub fn set(&mut self, k: usize, t: &NdfTable) {
        let (cells, w) = (self.grid.len(), self.words());
        write(self.grid, &mut self.values[k * cells..(k + 1) * cells], &mut self.coverage[k * w..(k + 1) * w], t);
    }

    /// Store table `k` of `other` (on the same grid) as table `k`, exactly
    /// as it is stored there.
    pub fn copy_from(&mut self, k: usize, other: &TableSet) {
        assert_eq!(self.grid, other.grid, "tables on one grid");
        let (cells, w) = (self.grid.len(), self.words());
        self.values[k * cells..(k + 1) * cells].copy_from_slice(&other.values[k * cells..(k + 1) * cells]);
        self.coverage[k * w..(k + 1) * w].copy_from_slice(other.coverage_words(k));
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

/// A [`TableSet`] kept in less memory while nothing reads its values: each
/// table's values at its covered cells only where all its others are zero
/// (+0: a per-point fit's table ends at its observed region, about half
/// the grid at the presets' plans), and all of them otherwise. Packing and
/// unpacking move the values within one allocation, so neither holds the
/// tables twice, and give the set back bit for bit.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedTables {
    grid: NdfGrid,
    len: usize,
    coverage: Vec<u64>,
    /// Tables kept whole: a value beyond their coverage is not +0.
    whole: Vec<bool>,
    values: Vec<f16>,
}

impl TableSet {
    /// The set in less memory ([`PackedTables`]).
    pub fn pack(self) -> PackedTables {
        let TableSet { grid, len, mut values, coverage } = self;
        let (cells, w) = (grid.len(), grid.len().div_ceil(64));
        let mut whole = Vec::with_capacity(len);
        let mut at = 0;
        for k in 0..len {
            let words = &coverage[k * w..(k + 1) * w];
            let table = k * cells..(k + 1) * cells;
            let all = values[table.clone()].iter().enumerate().any(|(c, v)| v.to_bits() != 0 && !bit(words, c));
            whole.push(all);
            // `at` never passes `table.start`: each table keeps at most
            // its own cells, so a value moves only towards the front.
            for c in (0..cells).filter(|&c| all || bit(words, c)) {
                values[at] = values[table.start + c];
                at += 1;
            }
        }
        values.truncate(at);
        values.shrink_to_fit();
        PackedTables { grid, len, coverage, whole, values }
    }
}

impl PackedTables {
    pub fn bytes(&self) -> usize {
        self.values.len() * 2 + self.coverage.len() * 8 + self.whole.len()
    }

    /// The set as it was packed, bit for bit.
    pub fn unpack(self) -> TableSet {
        let PackedTables { grid, len, coverage, whole, mut values } = self;
        let (cells, w) = (grid.len(), grid.len().div_ceil(64));
        let kept = |k: usize| if whole[k] { cells } else { (0..cells).filter(|&c| bit(&coverage[k * w..], c)).count() };
        let mut end = values.len();
        values.resize(len * cells, f16::ZERO);
        // From the last table's last cell back: a value moves only towards
        // the back, onto a place already read or never packed.
        for k in (0..len).rev() {
            let words = &coverage[k * w..(k + 1) * w];
            let start = end - kept(k);
            let mut from = end;
            for c in (0..cells).rev() {
                let to = k * cells + c;
                if whole[k] || bit(words, c) {
                    from -= 1;
                    values[to] = values[from];
                } else {
                    values[to] = f16::ZERO;
                }
            }
            debug_assert_eq!(from, start);
            end = start;
        }
        TableSet { grid, len, values, coverage }
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

/// How every reader takes a stored table: each value as f32, negative
/// values and NaN (a damaged file) as 0, and a table holding an infinite
/// value (one beyond `f16`'s range when it was stored) as all zero. A
/// whole table at once (converted by `half`'s slice conversion); false
/// where it reads as all zero.
fn read_values(values: &[f16], out: &mut [f32]) -> bool {
    values.convert_to_f32_slice(out);
    if out.contains(&f32::INFINITY) {
        out.fill(0.0);
        return false;
    }
    out.iter_mut().for_each(|v| *v = v.max(0.0));
    true
}

/// [`read_values`]' rule one cell at a time: whether the table reads as
/// other than all zero, and each cell's value where it does.
fn readable(values: &[f16]) -> bool {
    !values.iter().any(|v| v.to_bits() == f16::INFINITY.to_bits())
}

fn value(v: f16) -> f32 {
    v.to_f32().max(0.0)
}

fn read(grid: NdfGrid, values: &[f16], words: &[u64]) -> NdfTable {
    let mut out = vec![0.0f32; values.len()];
    if !read_values(values, &mut out) {
        return NdfTable::zeros(grid);
    }
    let values = out;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_reader_takes_a_stored_table_the_same_way() {
        let grid = NdfGrid::new(4, 8).unwrap();
        let cells = grid.len();
        let mut values: Vec<f16> = (0..3 * cells).map(|c| f16::from_f32(c as f32 * 0.25)).collect();
        // Table 1 from a damaged file: a negative value and a NaN; table 2
        // holds a value beyond f16's range (stored as infinity).
        values[cells + 3] = f16::from_f32(-2.0);
        values[cells + 5] = f16::NAN;
        values[2 * cells + 7] = f16::from_f32(1e6);
        let set = TableSet::from_raw(grid, 3, values, vec![u64::MAX; 3]).unwrap();
        let mut into = vec![-1.0f32; cells];
        for k in 0..3 {
            let got = set.get(k);
            set.values_into(k, &mut into);
            assert_eq!(got.values(), &into[..], "table {k}");
            match set.cells(k) {
                Some(value) => assert!((0..cells).all(|c| value(c) == into[c]), "table {k}"),
                None => assert!(into.iter().all(|&v| v == 0.0), "table {k}"),
            }
        }
        assert_eq!(set.get(0).values()[9], 9.0 * 0.25);
        assert_eq!(
            (set.get(1).values()[3], set.get(1).values()[5], set.get(1).values()[4]),
            (0.0, 0.0, (cells + 4) as f32 * 0.25)
        );
        assert!(set.cells(2).is_none() && set.get(2).values().iter().all(|&v| v == 0.0));
    }

    /// A copied table is stored as it was, bit for bit, even one no reader
    /// takes as stored (a negative value, a NaN, coverage beyond a grid's
    /// last word), and its neighbours are untouched.
    #[test]
    fn a_copied_table_is_stored_bit_for_bit() {
        let grid = NdfGrid::new(4, 20).unwrap();
        let (cells, words) = (grid.len(), grid.len().div_ceil(64));
        let mut values: Vec<f16> = (0..3 * cells).map(|c| f16::from_f32(c as f32 * 0.5 - 7.0)).collect();
        values[cells + 2] = f16::NAN;
        let coverage: Vec<u64> = (0..3 * words as u64).map(|w| w.wrapping_mul(0x9E37_79B9_7F4A_7C15)).collect();
        let from = TableSet::from_raw(grid, 3, values, coverage).unwrap();
        let mut to = TableSet::new(grid, 3);
        to.copy_from(1, &from);
        let (tv, tc) = to.raw();
        let (fv, fc) = from.raw();
        let bits = |v: &[f16]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&tv[cells..2 * cells]), bits(&fv[cells..2 * cells]));
        assert_eq!(tc[words..2 * words], fc[words..2 * words]);
        assert!(tv[..cells].iter().chain(&tv[2 * cells..]).all(|x| x.to_bits() == 0));
        assert!(tc[..words].iter().chain(&tc[2 * words..]).all(|&w| w == 0));
    }

    /// Packed and unpacked, a set is the same bit for bit: tables zero
    /// beyond their coverage (kept at their covered cells), tables with a
    /// value there (a -0, a NaN, a positive value: kept whole), empty and
    /// full coverage, stray bits past the grid's last cell, on a grid of
    /// whole and part words. Only what is kept is held.
    #[test]
    fn a_packed_set_unpacks_bit_for_bit() {
        for grid in [NdfGrid::new(4, 20).unwrap(), NdfGrid::new(8, 16).unwrap()] {
            let (cells, words) = (grid.len(), grid.len().div_ceil(64));
            let len = 9;
            let mut coverage: Vec<u64> =
                (0..(len * words) as u64).map(|w| w.wrapping_mul(0x9E37_79B9_7F4A_7C15)).collect();
            coverage[..words].fill(0);
            coverage[words..2 * words].fill(u64::MAX);
            let covered = |k: usize, c: usize| bit(&coverage[k * words..], c);
            let mut values = vec![f16::ZERO; len * cells];
            for k in 0..len {
                for c in (0..cells).filter(|&c| covered(k, c)) {
                    values[k * cells + c] = f16::from_f32((k * cells + c) as f32 * 0.125 - 3.0);
                }
            }
            let outside = |k: usize| (0..cells).find(|&c| !covered(k, c)).unwrap();
            values[4 * cells + outside(4)] = f16::NEG_ZERO;
            values[5 * cells + outside(5)] = f16::NAN;
            values[6 * cells + outside(6)] = f16::from_f32(0.5);
            values[7 * cells + 1] = f16::INFINITY;
            let set = TableSet::from_raw(grid, len, values, coverage.clone()).unwrap();
            let packed = set.clone().pack();
            let kept: usize = (0..len)
                .map(|k| if (4..=6).contains(&k) { cells } else { (0..cells).filter(|&c| covered(k, c)).count() })
                .sum();
            assert_eq!(packed.bytes(), kept * 2 + coverage.len() * 8 + len, "{grid:?}");
            assert!(packed.bytes() < set.bytes());
            let back = packed.unpack();
            let bits = |s: &TableSet| s.raw().0.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&back), bits(&set), "{grid:?}");
            assert_eq!(back.raw().1, set.raw().1);
            assert_eq!((back.grid(), back.len()), (grid, len));
        }
    }

    /// A copy that writes only the tables that are not blank is the set
    /// `clone` makes: blank tables, a -0, coverage alone, values alone.
    #[test]
    fn a_copy_of_the_written_tables_is_the_clone() {
        let grid = NdfGrid::new(4, 20).unwrap();
        let (cells, words) = (grid.len(), grid.len().div_ceil(64));
        let len = 6;
        let mut values = vec![f16::ZERO; len * cells];
        let mut coverage = vec![0u64; len * words];
        values[cells + 7] = f16::NEG_ZERO;
        coverage[2 * words + 1] = 1 << 5;
        values[3 * cells + cells - 1] = f16::from_f32(0.75);
        values[5 * cells] = f16::NAN;
        coverage[5 * words] = 3;
        let set = TableSet::from_raw(grid, len, values, coverage).unwrap();
        let blank: Vec<bool> = (0..len).map(|k| set.is_blank(k)).collect();
        assert_eq!(blank, [true, false, false, false, true, false]);
        let copy = set.clone_written();
        let bits = |s: &TableSet| s.raw().0.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&copy), bits(&set));
        assert_eq!(copy.raw().1, set.raw().1);
        assert!((0..len).all(|k| TableSet::new(grid, len).is_blank(k)));
    }
}
