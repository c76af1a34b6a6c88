//! Per-(light, point) reflectance samples, stored as the fitter's working set.
//!
//! Memory plan: each sample has a flag byte, light-major (`light * n_points +
//! point`), and, unless the geometry rules it out (out of view, too dim at
//! grazing incidence, hidden by the bar: [`flag::NO_REFLECTANCE`]), three
//! `f16` reflectances (6 bytes). A light's reflectances are kept in point
//! order, for its samples that hold one only; a bit per sample and a running
//! count per 64 points find a sample's place among them (16 bytes a word:
//! a quarter byte a sample). At the presets' plans over half the samples
//! are ruled out (balanced satin: 42% usable, 47% dim, 11% occluded), so
//! the talk's scale, 800 x 800 points x 2,560 lights = 1.64 G samples, holds
//! about 6.4 GB where a dense store held 11.5 GB, with room for the NDF tables
//! (`f16`, 3.9 GB at 3,072 cells). `f16` keeps 11 significant bits (0.05%
//! relative), far below the sensor's shot noise (about 1% at mid-scale), and
//! spans 6e-5 to 65,504, more than any reflectance a 12- or 16-bit camera
//! can measure. A store may hold a range of the grid's points only (one tile
//! of a fit spread over machines, see [`crate::TilePipeline`]); its points
//! keep their grid indices.

use half::f16;

/// Sample flag bits.
pub mod flag {
    /// No frame has provided this sample (yet).
    pub const MISSING: u8 = 0x01;
    /// The light bar hid the point from the camera.
    pub const OCCLUDED: u8 = 0x02;
    /// Every exposure of this light clipped at the point.
    pub const SATURATED: u8 = 0x04;
    /// Light at grazing incidence or too dim for a useful measurement.
    pub const DIM: u8 = 0x08;
    /// The point is outside the camera's view.
    pub const OUT_OF_VIEW: u8 = 0x10;
    /// Bits 5-6: index of the exposure the value came from.
    pub const EXPOSURE_SHIFT: u8 = 5;
    pub const EXPOSURE_MASK: u8 = 0x60;
    /// Any of these makes a sample unusable.
    pub const UNUSABLE: u8 = MISSING | OCCLUDED | SATURATED | DIM | OUT_OF_VIEW;
    /// A sample flagged with any of these holds no reflectance: the store
    /// keeps none for it, and reads it as zero. They are the classes the
    /// geometry decides (the same for every exposure of a light).
    pub const NO_REFLECTANCE: u8 = OCCLUDED | DIM | OUT_OF_VIEW;
}

/// 64 samples of one light's row: which of them hold a reflectance, and how
/// many of the row's samples before them do.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Word {
    held: u64,
    before: u32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SampleStore {
    /// Grid index of the store's first point.
    first: usize,
    n_points: usize,
    n_lights: usize,
    flags: Vec<u8>,
    /// `words()` a light, light-major.
    index: Vec<Word>,
    /// Each light's reflectances, of the samples its index holds.
    rho: Vec<Vec<[f16; 3]>>,
}

impl SampleStore {
    pub fn new(n_points: usize, n_lights: usize) -> Self {
        Self::for_points(0..n_points, n_lights)
    }

    /// A store for the grid's points `points` only. Every sample is
    /// missing, and no light's row holds a reflectance until it is written.
    pub fn for_points(points: std::ops::Range<usize>, n_lights: usize) -> Self {
        let n = points.len();
        // A row's count before a word is a u32.
        assert!(n <= u32::MAX as usize, "{n} points in one store");
        Self {
            first: points.start,
            n_points: n,
            n_lights,
            flags: vec![flag::MISSING; n * n_lights],
            index: vec![Word::default(); n.div_ceil(64) * n_lights],
            rho: vec![Vec::new(); n_lights],
        }
    }

    /// The grid indices of the points held.
    pub fn points(&self) -> std::ops::Range<usize> {
        self.first..self.first + self.n_points
    }

    /// Bytes held (for the memory report).
    pub fn bytes(&self) -> usize {
        self.flags.len()
            + self.index.len() * std::mem::size_of::<Word>()
            + self.rho.iter().map(|r| r.len() * 6).sum::<usize>()
    }

    pub fn n_points(&self) -> usize {
        self.n_points
    }

    pub fn n_lights(&self) -> usize {
        self.n_lights
    }

    fn words(&self) -> usize {
        self.n_points.div_ceil(64)
    }

    /// Where the reflectance of `light`'s sample at row position `i` lies
    /// in the light's row, if it holds one.
    #[inline]
    fn slot(&self, light: usize, i: usize) -> Option<usize> {
        let w = self.index[light * self.words() + i / 64];
        let bit = 1u64 << (i % 64);
        (w.held & bit != 0).then(|| w.before as usize + (w.held & (bit - 1)).count_ones() as usize)
    }

    /// The sample of `light` at grid point `point` (one the store holds).
    #[inline]
    pub fn get(&self, light: usize, point: usize) -> ([f32; 3], u8) {
        let i = point - self.first;
        let f = self.flags[light * self.n_points + i];
        let slot = if f & flag::NO_REFLECTANCE == 0 { self.slot(light, i) } else { None };
        let r = slot.map_or([f16::ZERO; 3], |s| self.rho[light][s]);
        ([r[0].to_f32(), r[1].to_f32(), r[2].to_f32()], f)
    }

    /// Ask the processor to start loading the flag of `light` at `point`
    /// and where its reflectance lies (a hint: it changes no value). A
    /// point's samples lie a whole row of points apart, one cache line
    /// each, too far apart for the hardware's own prefetcher; a loop over
    /// a point's lights asks a few lights ahead, and asks for the
    /// reflectance itself ([`Self::prefetch_sample`]) once its place is
    /// loaded.
    #[inline]
    pub fn prefetch(&self, light: usize, point: usize) {
        if point >= self.first && point - self.first < self.n_points && light < self.n_lights {
            let i = point - self.first;
            prefetch(&self.flags[light * self.n_points + i]);
            prefetch(&self.index[light * self.words() + i / 64]);
        }
    }

    /// Ask the processor to start loading the reflectance of `light` at
    /// `point` (a hint: it changes no value). Its place is read, so it
    /// pays when [`Self::prefetch`] asked for that a few lights before.
    #[inline]
    pub fn prefetch_sample(&self, light: usize, point: usize) {
        if point >= self.first
            && point - self.first < self.n_points
            && light < self.n_lights
            && let Some(s) = self.slot(light, point - self.first)
        {
            prefetch(&self.rho[light][s]);
        }
    }

    /// One light's reflectances over the points held, zero where a sample
    /// holds none (element `i` is grid point `points().start + i`).
    pub fn rho_row(&self, light: usize) -> Vec<[f16; 3]> {
        let mut row = vec![[f16::ZERO; 3]; self.n_points];
        let (words, held) = (&self.index[light * self.words()..(light + 1) * self.words()], &self.rho[light]);
        for (k, w) in words.iter().enumerate() {
            let mut bits = w.held;
            let mut s = w.before as usize;
            while bits != 0 {
                row[k * 64 + bits.trailing_zeros() as usize] = held[s];
                bits &= bits - 1;
                s += 1;
            }
        }
        row
    }

    /// One light's flags over the points held.
    pub fn flag_row(&self, light: usize) -> &[u8] {
        &self.flags[light * self.n_points..(light + 1) * self.n_points]
    }

    /// Change one light's row over the points held: `edit` gets its
    /// reflectances (zero where a sample holds none) and flags, element
    /// `i` being grid point `points().start + i`. Afterwards the row keeps
    /// a reflectance for each sample not flagged [`flag::NO_REFLECTANCE`],
    /// and drops the others' (which should be zero).
    pub fn edit_row<R>(&mut self, light: usize, edit: impl FnOnce(&mut [[f16; 3]], &mut [u8]) -> R) -> R {
        let mut rho = self.rho_row(light);
        let (n, words) = (self.n_points, self.words());
        let flags = &mut self.flags[light * n..(light + 1) * n];
        let out = edit(&mut rho, flags);
        let index = &mut self.index[light * words..(light + 1) * words];
        let mut count = 0u32;
        for (w, chunk) in index.iter_mut().zip(flags.chunks(64)) {
            let held =
                chunk.iter().enumerate().fold(0u64, |b, (j, &f)| b | (((f & flag::NO_REFLECTANCE == 0) as u64) << j));
            *w = Word { held, before: count };
            count += held.count_ones();
        }
        let kept = &mut self.rho[light];
        kept.clear();
        kept.reserve_exact(count as usize);
        kept.extend(rho.iter().zip(flags.iter()).filter(|(_, f)| **f & flag::NO_REFLECTANCE == 0).map(|(r, _)| *r));
        out
    }

    /// The reflectances one light's row holds, in point order, to change
    /// in place (a sample without one reads as zero whatever is done here).
    pub fn held_rho_mut(&mut self, light: usize) -> &mut [[f16; 3]] {
        &mut self.rho[light]
    }

    /// Exposure index recorded in a flag byte.
    pub fn exposure_of(flags: u8) -> u8 {
        (flags & flag::EXPOSURE_MASK) >> flag::EXPOSURE_SHIFT
    }

    /// Count samples per flag class (for the report).
    pub fn census(&self) -> Census {
        let mut c = Census::default();
        for &f in &self.flags {
            if f & flag::UNUSABLE == 0 {
                c.usable += 1;
            }
            if f & flag::MISSING != 0 {
                c.missing += 1;
            }
            if f & flag::OCCLUDED != 0 {
                c.occluded += 1;
            }
            if f & flag::SATURATED != 0 {
                c.saturated += 1;
            }
            if f & flag::DIM != 0 {
                c.dim += 1;
            }
        }
        c
    }
}

/// Ask the processor to start loading `x`'s cache line.
#[inline]
fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch never faults and reads nothing into the program;
    // the pointer is a reference's.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((x as *const T).cast())
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// Sample counts by class.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Census {
    pub usable: u64,
    pub missing: u64,
    pub occluded: u64,
    pub saturated: u64,
    pub dim: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(q: usize, i: usize) -> [f16; 3] {
        [q as f32 + 0.25, i as f32, -(i as f32) / 8.0].map(f16::from_f32)
    }

    /// A flag byte of every class and exposure, some ruling a reflectance out.
    fn flag_at(q: usize, i: usize) -> u8 {
        let classes = [0, flag::SATURATED, flag::DIM, flag::OCCLUDED, flag::OUT_OF_VIEW, flag::MISSING];
        classes[(q * 7 + i * 3 + i / 5) % classes.len()] | (((i % 3) as u8) << flag::EXPOSURE_SHIFT)
    }

    /// Rows of 1, 63, 64, 65 and 200 points, from grid point 0 or 37: each
    /// sample reads back what was written, zero where its flag rules a
    /// reflectance out, and only the others' reflectances are kept.
    #[test]
    fn a_written_row_reads_back_its_samples() {
        for (n, first) in [(1, 0), (63, 37), (64, 0), (65, 37), (200, 0), (200, 37)] {
            let lights = 3;
            let mut s = SampleStore::for_points(first..first + n, lights);
            for q in 0..lights {
                s.edit_row(q, |rho, fl| {
                    for i in 0..n {
                        fl[i] = flag_at(q, i);
                        rho[i] = if fl[i] & flag::NO_REFLECTANCE == 0 { value(q, i) } else { [f16::ZERO; 3] };
                    }
                });
            }
            let mut held = 0;
            for q in 0..lights {
                for i in 0..n {
                    let (r, f) = s.get(q, first + i);
                    assert_eq!(f, flag_at(q, i), "n {n} light {q} point {i}");
                    let want = if f & flag::NO_REFLECTANCE == 0 { value(q, i) } else { [f16::ZERO; 3] };
                    assert_eq!(r, want.map(f16::to_f32), "n {n} light {q} point {i}");
                    held += (f & flag::NO_REFLECTANCE == 0) as usize;
                }
                assert_eq!(s.flag_row(q), (0..n).map(|i| flag_at(q, i)).collect::<Vec<_>>());
                assert_eq!(s.rho_row(q).len(), n);
            }
            assert_eq!(s.bytes(), n * lights + n.div_ceil(64) * lights * 16 + held * 6, "n {n}");
        }
    }

    #[test]
    fn an_unwritten_row_is_missing_and_zero() {
        let s = SampleStore::for_points(5..75, 2);
        for p in 5..75 {
            assert_eq!(s.get(1, p), ([0.0; 3], flag::MISSING));
        }
        assert_eq!(s.census(), Census { missing: 140, ..Census::default() });
    }

    /// A second edit may change which samples hold a reflectance (a later
    /// exposure, a tile read over a whole grid's row): the row follows
    /// its flags, and the samples it keeps keep their values.
    #[test]
    fn an_edit_moves_samples_in_and_out_of_the_row() {
        let n = 130;
        let mut s = SampleStore::new(n, 1);
        s.edit_row(0, |rho, fl| {
            for i in 0..n {
                fl[i] = if i % 2 == 0 { 0 } else { flag::DIM };
                rho[i] = if i % 2 == 0 { value(0, i) } else { [f16::ZERO; 3] };
            }
        });
        s.edit_row(0, |rho, fl| {
            for i in (0..n).filter(|i| i % 3 == 0) {
                fl[i] = if i % 2 == 0 { flag::OCCLUDED } else { flag::SATURATED };
                rho[i] = if i % 2 == 0 { [f16::ZERO; 3] } else { value(0, i) };
            }
        });
        for i in 0..n {
            let (r, f) = s.get(0, i);
            let held = if i % 3 == 0 { i % 2 == 1 } else { i % 2 == 0 };
            assert_eq!(f & flag::NO_REFLECTANCE == 0, held, "{i}");
            assert_eq!(r, if held { value(0, i).map(f16::to_f32) } else { [0.0; 3] }, "{i}");
        }
    }

    /// Changing the held reflectances in place is the same as changing the
    /// whole row.
    #[test]
    fn held_reflectances_change_in_place() {
        let n = 100;
        let mut a = SampleStore::new(n, 2);
        for q in 0..2 {
            a.edit_row(q, |rho, fl| {
                for i in 0..n {
                    fl[i] = flag_at(q, i);
                    rho[i] = if fl[i] & flag::NO_REFLECTANCE == 0 { value(q, i) } else { [f16::ZERO; 3] };
                }
            });
        }
        let mut b = a.clone();
        let half = |r: &mut [f16; 3]| *r = r.map(|x| f16::from_f32(x.to_f32() * 0.5));
        a.held_rho_mut(1).iter_mut().for_each(half);
        b.edit_row(1, |rho, _| rho.iter_mut().for_each(half));
        assert_eq!(a, b);
        let held = (0..n).find(|&i| flag_at(1, i) & flag::NO_REFLECTANCE == 0).unwrap();
        assert_eq!(a.get(1, held).0, value(1, held).map(|x| x.to_f32() * 0.5));
    }
}
