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

    /// The lobes when each is a single lobe of closed form (not flattened,
    /// as [`Mixture::beckmann_lobes`]).
    fn closed_form_lobes(&self) -> Option<Vec<(f32, super::Lobe)>> {
        self.lobes
            .iter()
            .map(|(w, n)| match n.closed_form_lobes()?.as_slice() {
                [(1.0, l)] => Some((*w, l.clone())),
                _ => None,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ndf::{Beckmann, Lobe, Sheen};

    /// A mixture of single lobes lists them with its weights, in order; a
    /// mixture with a lobe that is itself a mixture lists none (its sums
    /// would be taken in another order than the renderer's).
    #[test]
    fn a_mixture_of_single_lobes_lists_them_and_a_nested_one_does_not() {
        let sheen = Sheen::new(0.35, 6.0);
        let b = Beckmann::isotropic(0.5);
        let m = Mixture::new(vec![(0.8, Arc::new(sheen.clone()) as Arc<dyn Ndf>), (0.2, Arc::new(b))]).unwrap();
        assert_eq!(m.closed_form_lobes(), Some(vec![(0.8, Lobe::Sheen(sheen)), (0.2, Lobe::Beckmann(b))]));
        assert_eq!(m.beckmann_lobes(), None);
        let nested = Mixture::new(vec![(0.5, Arc::new(m) as Arc<dyn Ndf>), (0.5, Arc::new(b))]).unwrap();
        assert_eq!(nested.closed_form_lobes(), None);
    }
}
