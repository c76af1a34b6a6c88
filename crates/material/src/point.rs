//! The reflectance of one point of a material.

use std::f32::consts::FRAC_1_PI;
use std::sync::Arc;

use brdf::fresnel::Fresnel;
use brdf::model::{Brdf, BrdfSample, Microfacet};
use brdf::ndf::Ndf;
use brdf::{Rgb, frame};
use glam::{Vec2, Vec3};

/// One point's BRDF: a diffuse term plus either nothing, the talk's
/// microfacet specular term (any NDF, analytic or tabulated), or any other
/// model (the analytic fits).
#[derive(Clone)]
pub enum PointMaterial {
    Diffuse { kd: Rgb },
    Microfacet(Microfacet<Arc<dyn Ndf>>),
    Model(Arc<dyn Brdf>),
}

impl std::fmt::Debug for PointMaterial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PointMaterial::Diffuse { kd } => f.debug_struct("Diffuse").field("kd", kd).finish(),
            PointMaterial::Microfacet(m) => {
                f.debug_struct("Microfacet").field("kd", &m.kd).field("ks", &m.ks).field("fresnel", &m.fresnel).finish()
            }
            PointMaterial::Model(_) => f.write_str("Model"),
        }
    }
}

impl PointMaterial {
    pub fn microfacet(kd: Rgb, ks: Rgb, ndf: Arc<dyn Ndf>, fresnel: Fresnel) -> Self {
        PointMaterial::Microfacet(Microfacet { kd, ks, ndf, fresnel })
    }

    /// A fitted point's BRDF from its maps: the fitted microfacet model
    /// `kd/pi + ks D F_rel / (4 sigma sigma)` with relative Fresnel of index
    /// `eta`, or diffuse alone when it has no specular albedo or no NDF.
    /// The one way fitted maps become a BRDF (material views, hold-out
    /// prediction, tests).
    pub fn fitted(kd: Rgb, ks: Rgb, eta: f32, ndf: Option<Arc<dyn Ndf>>) -> Self {
        match ndf {
            Some(ndf) if ks.max_element() > 0.0 => Self::microfacet(kd, ks, ndf, Fresnel::DielectricRelative { eta }),
            _ => PointMaterial::Diffuse { kd },
        }
    }

    /// The NDF a fitted table describes (with its masking from `op`), or
    /// `None` for a table that holds no mass.
    pub fn table_ndf(table: brdf::ndf::NdfTable, op: &brdf::ndf::MaskingOperator) -> Option<Arc<dyn Ndf>> {
        if !(table.integral_cos() > 0.0) {
            return None;
        }
        Some(Arc::new(brdf::ndf::TabulatedNdf::new(table, op)))
    }

    /// Diffuse albedo.
    pub fn kd(&self) -> Rgb {
        match self {
            PointMaterial::Diffuse { kd } => *kd,
            PointMaterial::Microfacet(m) => m.kd,
            PointMaterial::Model(_) => Vec3::ZERO,
        }
    }

    /// The NDF, if the specular term is microfacet.
    pub fn ndf(&self) -> Option<&Arc<dyn Ndf>> {
        match self {
            PointMaterial::Microfacet(m) => Some(&m.ndf),
            _ => None,
        }
    }
}

impl Brdf for PointMaterial {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        match self {
            PointMaterial::Diffuse { kd } => {
                if i.z > 0.0 && o.z > 0.0 {
                    kd.max(Vec3::ZERO) * FRAC_1_PI
                } else {
                    Vec3::ZERO
                }
            }
            PointMaterial::Microfacet(m) => m.eval(i, o),
            PointMaterial::Model(b) => b.eval(i, o),
        }
    }

    fn sample(&self, o: Vec3, u: Vec2) -> Option<BrdfSample> {
        match self {
            PointMaterial::Diffuse { .. } => {
                let i = frame::sample_cosine_hemisphere(u);
                Some(BrdfSample { i, pdf: frame::cosine_hemisphere_pdf(i) }).filter(|s| s.pdf > 0.0 && o.z > 0.0)
            }
            PointMaterial::Microfacet(m) => m.sample(o, u),
            PointMaterial::Model(b) => b.sample(o, u),
        }
    }

    fn pdf(&self, o: Vec3, i: Vec3) -> f32 {
        match self {
            PointMaterial::Diffuse { .. } => frame::cosine_hemisphere_pdf(i),
            PointMaterial::Microfacet(m) => m.pdf(o, i),
            PointMaterial::Model(b) => b.pdf(o, i),
        }
    }
}

/// A spatially varying BRDF over the sample plane (positions in mm, local
/// frame = sample frame).
pub trait SvBrdf: Send + Sync {
    fn name(&self) -> &str;
    /// The BRDF at a point of the sample.
    fn at(&self, p_mm: Vec2) -> PointMaterial;
}

impl<T: SvBrdf + ?Sized> SvBrdf for Arc<T> {
    fn name(&self) -> &str {
        (**self).name()
    }
    fn at(&self, p_mm: Vec2) -> PointMaterial {
        (**self).at(p_mm)
    }
}
