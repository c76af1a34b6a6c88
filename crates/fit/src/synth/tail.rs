//! The cells no match covers: the lobe's tail.
//!
//! Synthesis completes a cell only where some other point, rotated, observed
//! it. Where every point sees the lobe from about the same side (a
//! homogeneous sample, or a lobe that turns little), the cells beyond all
//! of their regions stay empty, and normalising over the hemisphere then
//! moves their mass onto the observed cells. Balanced `ward` on the ideal
//! rig: the truth has 1.6% of its mass on the cells left empty, and the
//! observed cells came out 1.7% high (`refl eval`'s
//! `ndf_true_mass_uncovered` and `ndf_scale_observed`).
//!
//! A lobe's tail is smooth, so the empty cells take a fitted lobe instead of
//! nothing: Beckmann's form with any anisotropy, orientation and offset,
//! that is `ln(D cos^4 theta)` quadratic in the slopes `(h_x / h_z,
//! h_y / h_z)`. It is fitted by weighted least squares to the lobe's body:
//! the covered cells holding at least [`MIN_RELATIVE`] of the peak and
//! joined to it, each weighted by its mass (`D cos theta dw`). The fit
//! fills nothing when it does not fall off in every direction, or when the
//! covered cells beside the empty ones are not within a factor of two of it
//! (their least-squares level): there the table is not such a lobe, and an
//! empty cell is better than a guess. No filled value exceeds the table's
//! largest covered one. A lobe whose tail is heavier than Beckmann's (GGX)
//! mostly fails the border test and keeps its empty cells (balanced
//! vch_golden_yellow: every point). A GGX form was tried and dropped: a
//! weave's summed lobes fit it better than Beckmann's and took its heavy
//! tail (balanced red-satin's NDF error on observed cells 0.175 -> 0.200).

use brdf::ndf::NdfTable;
use nalgebra::{Matrix6, Vector6};

/// Covered cells below this fraction of the table's peak do not shape the
/// fit: their logarithm is mostly noise.
pub const MIN_RELATIVE: f32 = 0.05;

/// Fewest cells the fit takes (six parameters, with room for noise).
const MIN_CELLS: usize = 12;

/// The covered cells beside the empty ones must lie within these factors
/// of the fitted lobe (their least-squares level against it): a table that
/// the lobe misses where the two meet is not a lobe of that form, and its
/// empty cells are left empty rather than filled with a guess.
const LEVEL_RANGE: (f64, f64) = (0.5, 2.0);

/// The quadratic's features at slopes `(x, y)`.
fn features(x: f64, y: f64) -> Vector6<f64> {
    Vector6::new(1.0, x, y, x * x, x * y, y * y)
}

/// `table` with its empty cells (not covered, above the horizon) filled
/// from a lobe fitted to its covered ones and marked covered; `None` when
/// nothing is empty or the fit fails. Not renormalised.
pub fn fill(table: &NdfTable) -> Option<NdfTable> {
    fill_with(table, &Slopes::new(table.grid()))
}

/// Per cell of a grid, `cos^4` of its centre's polar angle and its slopes
/// `(x / z, y / z)`; `None` at the horizon. The same for every table on
/// the grid: find it once for many ([`fill_with`]).
#[derive(Debug)]
pub struct Slopes {
    grid: brdf::ndf::NdfGrid,
    cells: Vec<Option<(f64, f64, f64)>>,
    /// The grid's cosine measure per ring.
    measures: Vec<f32>,
}

impl Slopes {
    pub fn new(g: brdf::ndf::NdfGrid) -> Self {
        let np = g.n_phi as usize;
        let cells = (0..g.len())
            .map(|c| {
                let h = g.direction(c / np, c % np);
                let z = h.z as f64;
                (z > 1e-3).then(|| (z * z * z * z, h.x as f64 / z, h.y as f64 / z))
            })
            .collect();
        Self { grid: g, cells, measures: g.cos_measures() }
    }
}

/// [`fill`] with the grid's [`Slopes`] found before (for `table`'s grid;
/// another grid's are found again).
pub fn fill_with(table: &NdfTable, slopes: &Slopes) -> Option<NdfTable> {
    let g = table.grid();
    if slopes.grid != g {
        return fill(table);
    }
    let (nt, np) = (g.n_theta as usize, g.n_phi as usize);
    let cov = table.coverage();
    if cov.count() == g.len() {
        return None;
    }
    let measures = &slopes.measures;
    let slopes = &slopes.cells;
    let values = table.values();
    let (mut top, mut peak) = (0, 0.0f32);
    for c in cov.iter_set() {
        if values[c] > peak {
            (top, peak) = (c, values[c]);
        }
    }
    if !(peak > 0.0) || !peak.is_finite() {
        return None;
    }
    // The four neighbours around the ring and across it; a cell on the
    // first or last ring stands in for the one it lacks (each use below
    // finds nothing at the cell itself).
    let neighbours = |c: usize| {
        let (t, p) = (c / np, c % np);
        let up = if t > 0 { c - np } else { c };
        let down = if t + 1 < nt { c + np } else { c };
        let right = if p + 1 == np { c + 1 - np } else { c + 1 };
        let left = if p == 0 { c + np - 1 } else { c - 1 };
        [up, down, right, left]
    };
    // The body: the covered cells of at least MIN_RELATIVE of the peak
    // joined to it. A stray noisy cell far out, where a lobe's logarithm is
    // hundreds below the peak's, would otherwise outweigh the whole body.
    let mut body = vec![false; g.len()];
    let mut todo = vec![top];
    body[top] = true;
    while let Some(c) = todo.pop() {
        for d in neighbours(c) {
            if !body[d] && cov.get(d) && values[d] >= MIN_RELATIVE * peak && slopes[d].is_some() {
                body[d] = true;
                todo.push(d);
            }
        }
    }
    let (mut a, mut b, mut n) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros(), 0usize);
    for c in (0..g.len()).filter(|&c| body[c]) {
        let (v, Some((c4, x, y))) = (values[c], slopes[c]) else { continue };
        let w = (v * measures[c / np]) as f64;
        let f = features(x, y);
        a += w * f * f.transpose();
        b += w * (v as f64 * c4).ln() * f;
        n += 1;
    }
    if n < MIN_CELLS {
        return None;
    }
    let q = a.cholesky()?.solve(&b);
    // Falls off in every direction: the quadratic part is negative definite.
    if !(q[3] < 0.0 && 4.0 * q[3] * q[5] - q[4] * q[4] > 0.0) {
        return None;
    }
    let lobe = |c: usize| slopes[c].map_or(0.0, |(c4, x, y)| q.dot(&features(x, y)).exp() / c4);
    // Where the table meets its empty cells, the lobe must agree with it.
    let empty = |c: usize| !cov.get(c) && slopes[c].is_some();
    let (mut sab, mut sbb) = (0.0f64, 0.0f64);
    for c in cov.iter_set().filter(|&c| neighbours(c).into_iter().any(empty)) {
        let (l, w) = (lobe(c), measures[c / np] as f64);
        sab += w * l * values[c] as f64;
        sbb += w * l * l;
    }
    if sbb > 0.0 && !(LEVEL_RANGE.0..=LEVEL_RANGE.1).contains(&(sab / sbb)) {
        return None;
    }
    let mut out = table.clone();
    let mut added = false;
    for c in (0..g.len()).filter(|&c| empty(c)) {
        let v = lobe(c).min(peak as f64);
        out.values_mut()[c] = if v.is_finite() { v as f32 } else { 0.0 };
        out.coverage_mut().set(c, true);
        added = true;
    }
    added.then_some(out)
}

#[cfg(test)]
mod tests {
    use brdf::ndf::{Beckmann, Coverage, NdfGrid, NdfTable};

    use super::*;

    /// A Beckmann table, normalised, with the cells at `(theta, phi)` that
    /// `keep` refuses empty (0, not covered); and the full table.
    fn holed(ndf: &Beckmann, grid: NdfGrid, keep: impl Fn(f32, f32) -> bool) -> (NdfTable, NdfTable) {
        let mut truth = NdfTable::from_ndf(grid, ndf);
        truth.normalize();
        let np = grid.n_phi as usize;
        let mut cov = Coverage::empty(grid.len());
        let mut values = truth.values().to_vec();
        for c in 0..grid.len() {
            if keep(grid.theta_center(c / np), grid.phi_center(c % np)) {
                cov.set(c, true);
            } else {
                values[c] = 0.0;
            }
        }
        (NdfTable::from_values(grid, values, cov).unwrap(), truth)
    }

    fn mass(t: &NdfTable, cells: impl Fn(usize) -> bool) -> f64 {
        let g = t.grid();
        (0..g.len()).filter(|&c| cells(c)).map(|c| (t.values()[c] * g.cos_measure(c / g.n_phi as usize)) as f64).sum()
    }

    #[test]
    fn a_beckmann_lobe_s_missing_side_is_restored() {
        // Balanced ward's lobe, its long side cut off where a rig does not see it.
        let grid = NdfGrid::new(32, 96).unwrap();
        let ndf = Beckmann::new(0.1, 0.3, 30f32.to_radians());
        let (holed, truth) =
            holed(&ndf, grid, |t, p| t < 25f32.to_radians() || (p > 1.0 && p < 4.0 && t < 60f32.to_radians()));
        let lost = mass(&truth, |c| !holed.coverage().get(c));
        assert!(lost > 0.01, "the cut must lose a visible share of the mass, lost {lost}");
        let filled = fill(&holed).expect("a Beckmann lobe is fitted");
        let restored = mass(&filled, |c| !holed.coverage().get(c));
        // The table holds the lobe to f32 and its cells' averages; the fit
        // of a Beckmann lobe to it is exact but for that.
        assert!((restored - lost).abs() < 0.02 * lost, "restored {restored} of {lost}");
        assert_eq!(filled.coverage().count(), grid.len(), "every cell is covered after the fill");
        for c in holed.coverage().iter_set() {
            assert_eq!(filled.values()[c], holed.values()[c], "covered cells are kept");
        }
    }

    #[test]
    fn a_table_that_does_not_fall_off_fills_nothing() {
        // `D cos^4 theta = 1 + tan^2 theta`, rising away from the normal: no lobe.
        let grid = NdfGrid::new(16, 48).unwrap();
        let np = grid.n_phi as usize;
        let mut cov = Coverage::empty(grid.len());
        let mut values = vec![0.0; grid.len()];
        for c in 0..grid.len() {
            let t = grid.theta_center(c / np);
            if t < 50f32.to_radians() {
                cov.set(c, true);
                values[c] = t.cos().powi(-6);
            }
        }
        assert!(fill(&NdfTable::from_values(grid, values, cov).unwrap()).is_none());
    }

    #[test]
    fn a_full_table_is_left_alone() {
        let grid = NdfGrid::new(16, 48).unwrap();
        let t = NdfTable::from_ndf(grid, &Beckmann::new(0.2, 0.2, 0.0));
        assert!(t.coverage().count() == grid.len() && fill(&t).is_none());
    }
}
