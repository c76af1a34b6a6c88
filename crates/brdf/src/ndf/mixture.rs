//! A weighted mixture of NDFs, `D = sum_j w_j D_j` with `sum w_j = 1`.
//! Normalisation is inherited, and the projected area is linear in `D`, so
//! Smith masking of the mixture is exact: `sigma = sum_j w_j sigma_j`.
//! A satin's two thread directions are a mixture of two anisotropic lobes.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::Ndf;

#[derive(Clone)]
pub struct Mixture {
    lobes: Vec<(f32, Arc<dyn Ndf>)>,
}

impl std::fmt::Debug for Mixture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mixture").field("weights", &self.lobes.iter().map(|l| l.0).collect::<Vec<_>>()).finish()
    }
}

impl Mixture {
    /// Weights are normalised to sum to 1; non-positive or non-finite
    /// weights are dropped. An empty mixture is not allowed: `None`.
    pub fn new(lobes: Vec<(f32, Arc<dyn Ndf>)>) -> Option<Self> {
        let lobes: Vec<_> = lobes.into_iter().filter(|(w, _)| w.is_finite() && *w > 0.0).collect();
        let total: f32 = lobes.iter().map(|l| l.0).sum();
        if lobes.is_empty() || !(total > 0.0) {
            return None;
        }
        Some(Self { lobes: lobes.into_iter().map(|(w, n)| (w / total, n)).collect() })
    }

    pub fn lobes(&self) -> &[(f32, Arc<dyn Ndf>)] {
        &self.lobes
    }
}

impl Ndf for Mixture {
    fn d(&self, h: Vec3) -> f32 {
        self.lobes.iter().map(|(w, n)| w * n.d(h)).sum()
    }

    fn projected_area(&self, v: Vec3) -> f32 {
        let s: f32 = self.lobes.iter().map(|(w, n)| w * n.projected_area(v)).sum();
        s.max(v.z)
    }

    fn sample_h(&self, u: Vec2) -> Vec3 {
        let mut acc = 0.0;
        for (k, (w, n)) in self.lobes.iter().enumerate() {
            if u.x < acc + w || k + 1 == self.lobes.len() {
                let ux = ((u.x - acc) / w).clamp(0.0, 0.999_999_9);
                return n.sample_h(Vec2::new(ux, u.y));
            }
            acc += w;
        }
        Vec3::Z
    }

    fn pdf_h(&self, h: Vec3) -> f32 {
        self.lobes.iter().map(|(w, n)| w * n.pdf_h(h)).sum()
    }

    /// The lobes when each is a single Beckmann lobe (a mixture of
    /// mixtures is not flattened: its sums would be taken in another order).
    fn beckmann_lobes(&self) -> Option<Vec<(f32, super::Beckmann)>> {
        self.lobes
            .iter()
            .map(|(w, n)| match n.beckmann_lobes()?.as_slice() {
                [(1.0, b)] => Some((*w, *b)),
                _ => None,
            })
            .collect()
    }
}
