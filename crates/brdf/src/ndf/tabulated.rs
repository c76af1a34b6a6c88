//! A tabulated NDF ready for evaluation: the table, its Smith masking by
//! integration, and an importance sampler.
//!
//! Sampling picks a cell with probability `D_c * cos_measure_c` (the table's
//! own quadrature of `D cos`), then a direction inside the cell uniformly in
//! `(sin^2 theta, phi)`, which is uniform in the cosine measure. Its density
//! is therefore the piecewise-constant `D_c cos(theta)` (normalised), which
//! [`TabulatedNdf::pdf_h`] returns; evaluation interpolates bilinearly, so
//! `pdf_h` and `d * cos` agree at cell centres and differ slightly between
//! them. Both are exact for their own purpose: the sampler's pdf is the true
//! density of its samples (tested by chi-square).

use glam::{Vec2, Vec3};

use super::{MaskingOperator, MaskingTable, Ndf, NdfTable};

#[derive(Clone, Debug)]
pub struct TabulatedNdf {
    table: NdfTable,
    masking: MaskingTable,
    /// Cumulative cell masses, normalised to end at 1.
    cdf: Vec<f32>,
    /// Total mass `sum D_c cos_measure_c` before normalisation of the cdf.
    mass: f32,
}

impl TabulatedNdf {
    /// Build from a table (normalised or not: the table is used as given and
    /// the sampler normalises its own density).
    pub fn new(table: NdfTable, masking: &MaskingOperator) -> Self {
        let masking_table = masking.projected_areas(&table);
        let grid = table.grid();
        let np = grid.n_phi as usize;
        let mut cdf = Vec::with_capacity(grid.len());
        let mut acc = 0.0f64;
        for t in 0..grid.n_theta as usize {
            let w = grid.cos_measure(t) as f64;
            for p in 0..np {
                acc += table.at(t, p) as f64 * w;
                cdf.push(acc as f32);
            }
        }
        let mass = acc as f32;
        if mass > 0.0 {
            cdf.iter_mut().for_each(|c| *c /= mass);
        }
        Self { table, masking: masking_table, cdf, mass }
    }

    pub fn table(&self) -> &NdfTable {
        &self.table
    }

    pub fn masking(&self) -> &MaskingTable {
        &self.masking
    }
}

impl Ndf for TabulatedNdf {
    fn d(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 { 0.0 } else { self.table.eval(h) }
    }

    fn projected_area(&self, v: Vec3) -> f32 {
        self.masking.projected_area(v)
    }

    fn sample_h(&self, u: Vec2) -> Vec3 {
        let grid = self.table.grid();
        if !(self.mass > 0.0) {
            return Vec3::Z;
        }
        let idx = self.cdf.partition_point(|&c| c <= u.x).min(self.cdf.len() - 1);
        // Reuse the position of u.x inside the chosen cell's cdf interval as
        // the first in-cell coordinate (keeps stratification of u).
        let lo = if idx == 0 { 0.0 } else { self.cdf[idx - 1] };
        let hi = self.cdf[idx];
        let a = if hi > lo { ((u.x - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.5 };
        let (t, p) = (idx / grid.n_phi as usize, idx % grid.n_phi as usize);
        let (s0, s1) = (grid.theta_edge(t).sin().powi(2), grid.theta_edge(t + 1).sin().powi(2));
        let s2 = s0 + (s1 - s0) * a;
        let (st, ct) = (s2.sqrt(), (1.0 - s2).max(0.0).sqrt());
        let ph = (p as f32 + u.y) * grid.dphi();
        Vec3::new(st * ph.cos(), st * ph.sin(), ct)
    }

    fn pdf_h(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 || !(self.mass > 0.0) {
            return 0.0;
        }
        match self.table.grid().cell(h) {
            Some((t, p)) => self.table.at(t, p) * h.z / self.mass,
            None => 0.0,
        }
    }
}
