//! Evaluating a stored material: any of its models as an [`SvBrdf`].

use std::sync::{Arc, OnceLock};

use brdf::ndf::{MaskingOperator, Ndf};
use brdf::params::AnalyticModel;
use glam::{Vec2, Vec3};

use crate::data::{Choice, Material};
use crate::point::{PointMaterial, SvBrdf};

/// Which of a material's models to evaluate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelChoice {
    /// The main tables (synthesized when synthesis ran).
    Tabulated,
    /// The partial tables (before synthesis).
    Partial,
    Analytic(AnalyticModel),
    /// The per-region choice of "model only what the sample needs".
    Auto,
}

impl ModelChoice {
    /// Parse `synthesized`, `tabulated`, `partial`, `auto` or an analytic model's name.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "synthesized" | "tabulated" => Some(ModelChoice::Tabulated),
            "partial" => Some(ModelChoice::Partial),
            "auto" => Some(ModelChoice::Auto),
            other => AnalyticModel::from_name(other).map(ModelChoice::Analytic),
        }
    }
}

/// A material seen through one of its models. Tabulated NDFs (with their
/// masking tables and samplers) are built lazily, once per point.
pub struct MaterialView {
    material: Arc<Material>,
    choice: ModelChoice,
    masking: Option<Arc<MaskingOperator>>,
    cache: Vec<OnceLock<Option<Arc<dyn Ndf>>>>,
    /// The point shown at each grid point: itself, or for a point the
    /// camera could not measure ([`crate::data::UNMEASURED`]), its nearest
    /// measured neighbour.
    stand_in: Vec<u32>,
    name: String,
}

impl std::fmt::Debug for MaterialView {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MaterialView").field("material", &self.material.name).field("choice", &self.choice).finish()
    }
}

impl MaterialView {
    /// `None` if the material lacks the requested model.
    pub fn new(material: Arc<Material>, choice: ModelChoice) -> Option<Self> {
        let needs_tables = match choice {
            ModelChoice::Tabulated | ModelChoice::Auto => material.ndf.is_some(),
            ModelChoice::Partial => material.partial.is_some() || material.ndf.is_some(),
            ModelChoice::Analytic(m) => {
                if !material.models.contains_key(m.name()) {
                    return None;
                }
                false
            }
        };
        if matches!(choice, ModelChoice::Tabulated | ModelChoice::Partial) && !needs_tables {
            return None;
        }
        if choice == ModelChoice::Auto && material.choice.is_none() {
            return None;
        }
        let grid = material.ndf.as_ref().or(material.partial.as_ref().map(|pf| &pf.tables)).map(|t| t.grid());
        let masking = if needs_tables { grid.map(|g| Arc::new(MaskingOperator::new(g))) } else { None };
        let name = format!("{} ({choice:?})", material.name);
        let cache = (0..material.n_points()).map(|_| OnceLock::new()).collect();
        let stand_in = material.stand_ins();
        Some(Self { material, choice, masking, cache, stand_in, name })
    }

    pub fn material(&self) -> &Material {
        &self.material
    }

    fn table(&self, p: usize, partial: bool) -> Option<Arc<dyn Ndf>> {
        self.cache[p]
            .get_or_init(|| {
                let set = if partial {
                    self.material.partial.as_ref().map(|pf| &pf.tables).or(self.material.ndf.as_ref())
                } else {
                    self.material.ndf.as_ref()
                }?;
                PointMaterial::table_ndf(set.get(p), self.masking.as_ref()?)
            })
            .clone()
    }

    /// The BRDF of grid point `p`.
    pub fn point(&self, p: usize) -> PointMaterial {
        let m = &self.material;
        let kd = Vec3::from(m.kd[p]);
        let tabulated = |partial: bool| {
            // The partial tables with the ks and eta fitted with them.
            let (ks, eta) = match (&m.partial, partial) {
                (Some(pf), true) => (pf.ks[p], pf.eta[p]),
                _ => (m.ks[p], m.eta[p]),
            };
            PointMaterial::fitted(kd, Vec3::from(ks), eta, self.table(p, partial))
        };
        let analytic = |am: AnalyticModel| match m.models.get(am.name()).and_then(|mm| am.build(mm.point(p))) {
            Some(b) => PointMaterial::Model(b),
            None => PointMaterial::Diffuse { kd },
        };
        match self.choice {
            ModelChoice::Tabulated => tabulated(false),
            ModelChoice::Partial => tabulated(true),
            ModelChoice::Analytic(am) => analytic(am),
            ModelChoice::Auto => match m.choice.as_ref().map(|c| (c.choice[p], c)) {
                Some((Choice::Diffuse, _)) => PointMaterial::Diffuse { kd },
                Some((Choice::Isotropic, c)) => analytic(c.isotropic_model),
                Some((Choice::Anisotropic, c)) => analytic(c.anisotropic_model),
                _ => tabulated(false),
            },
        }
    }
}

impl SvBrdf for MaterialView {
    fn name(&self) -> &str {
        &self.name
    }

    fn at(&self, p_mm: Vec2) -> PointMaterial {
        match self.material.point_at(p_mm) {
            Some(p) => self.point(self.stand_in[p] as usize),
            None => PointMaterial::Diffuse { kd: Vec3::ZERO },
        }
    }
}
