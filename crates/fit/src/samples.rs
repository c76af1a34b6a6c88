//! Per-(light, point) reflectance samples, stored as the fitter's working set.
//!
//! Memory plan: each sample is three `f16` reflectances (6 bytes) and a flag
//! byte, light-major (`light * n_points + point`). A store may hold a range of the
//! grid's points only (one tile of a fit spread over machines, see
//! [`crate::TilePipeline`]); its points keep their grid indices. The talk's scale,
//! 800 x 800 points x 2,560 lights, is 1.64 G samples = 11.5 GB, which fits
//! this project's 24 GB machines with room for the NDF tables (`f16`,
//! 3.9 GB at 3,072 cells). `f16` keeps 11 significant bits (0.05%
//! relative), far below the sensor's shot noise (about 1% at mid-scale), and
//! spans 6e-5 to 65,504, more than any reflectance a 12- or 16-bit camera
//! can measure. A tile of consecutive points reads contiguous runs of each
//! light's row.

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
}

#[derive(Clone, Debug, PartialEq)]
pub struct SampleStore {
    /// Grid index of the store's first point.
    first: usize,
    n_points: usize,
    n_lights: usize,
    rho: Vec<[f16; 3]>,
    flags: Vec<u8>,
}

impl SampleStore {
    pub fn new(n_points: usize, n_lights: usize) -> Self {
        Self::for_points(0..n_points, n_lights)
    }

    /// A store for the grid's points `points` only.
    pub fn for_points(points: std::ops::Range<usize>, n_lights: usize) -> Self {
        let n = points.len() * n_lights;
        Self {
            first: points.start,
            n_points: points.len(),
            n_lights,
            rho: vec![[f16::ZERO; 3]; n],
            flags: vec![flag::MISSING; n],
        }
    }

    /// The grid indices of the points held.
    pub fn points(&self) -> std::ops::Range<usize> {
        self.first..self.first + self.n_points
    }

    /// Raw storage, light-major over the points held (for a tile file).
    pub fn raw(&self) -> (&[[f16; 3]], &[u8]) {
        (&self.rho, &self.flags)
    }

    /// Bytes held (for the memory report).
    pub fn bytes(&self) -> usize {
        self.rho.len() * 6 + self.flags.len()
    }

    pub fn n_points(&self) -> usize {
        self.n_points
    }

    pub fn n_lights(&self) -> usize {
        self.n_lights
    }

    /// The sample of `light` at grid point `point` (one the store holds).
    #[inline]
    pub fn get(&self, light: usize, point: usize) -> ([f32; 3], u8) {
        let k = light * self.n_points + (point - self.first);
        let r = self.rho[k];
        ([r[0].to_f32(), r[1].to_f32(), r[2].to_f32()], self.flags[k])
    }

    /// Ask the processor to start loading the sample of `light` at `point`
    /// (a hint: it changes no value). A point's samples lie a whole row
    /// of points apart, one cache line each, too far apart for the
    /// hardware's own prefetcher; a loop over a point's lights asks a few
    /// lights ahead.
    #[inline]
    pub fn prefetch(&self, light: usize, point: usize) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let k = light * self.n_points + point.wrapping_sub(self.first);
            if point >= self.first && k < self.flags.len() {
                // SAFETY: a prefetch never faults and reads nothing into
                // the program; both pointers are inside their vectors.
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(self.rho.as_ptr().add(k).cast());
                    _mm_prefetch::<_MM_HINT_T0>(self.flags.as_ptr().add(k).cast());
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (light, point);
    }

    /// Mutable access to one light's row over the points held (for ingest;
    /// element `i` is grid point `points().start + i`).
    pub fn row_mut(&mut self, light: usize) -> (&mut [[f16; 3]], &mut [u8]) {
        let r = light * self.n_points..(light + 1) * self.n_points;
        (&mut self.rho[r.clone()], &mut self.flags[r])
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

/// Sample counts by class.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Census {
    pub usable: u64,
    pub missing: u64,
    pub occluded: u64,
    pub saturated: u64,
    pub dim: u64,
}
