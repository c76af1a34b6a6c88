//! Completing a partial NDF from its matches.
//!
//! Every cell the query did not observe takes a weighted mean of its
//! matches' values there (each candidate rotated by its shift and scaled by
//! its least-squares scale onto the query), over the matches that cover
//! the cell. Weights are `1 / (distance^2 + DISTANCE_FLOOR^2)`: the closest
//! shapes dominate, and distances below the floor (equal shapes within
//! measurement noise) count equally. Observed cells are never changed.

use brdf::ndf::NdfTable;

use super::score::Match;

/// Distances below this are indistinguishable: the normalised correlation
/// of two noisy measurements of one NDF (about 5% noise per cell) reaches
/// `1 - 0.02^2 / 2`.
pub const DISTANCE_FLOOR: f32 = 0.02;

/// The query completed by its matches (`None` if they add nothing). The
/// result is not renormalised.
pub fn complete(query: &NdfTable, matches: &[(Match, &NdfTable)]) -> Option<NdfTable> {
    let g = query.grid();
    let rotated: Vec<(f32, f32, NdfTable)> = matches
        .iter()
        .map(|(m, t)| {
            (1.0 / (m.distance * m.distance + DISTANCE_FLOOR * DISTANCE_FLOOR), m.scale, t.rotated(m.shift * g.dphi()))
        })
        .collect();
    let mut out = query.clone();
    let mut added = false;
    for c in 0..g.len() {
        if query.coverage().get(c) {
            continue;
        }
        let (mut sv, mut sw) = (0.0f32, 0.0f32);
        for (w, scale, r) in &rotated {
            if r.coverage().get(c) {
                sv += w * scale * r.values()[c];
                sw += w;
            }
        }
        if sw > 0.0 {
            let v = sv / sw;
            out.values_mut()[c] = if v.is_finite() { v.max(0.0) } else { 0.0 };
            out.coverage_mut().set(c, true);
            added = true;
        }
    }
    added.then_some(out)
}
