//! Lambertian diffuse reflection, `f = albedo / pi`.

use std::f32::consts::FRAC_1_PI;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::{Brdf, both_above};
use crate::Rgb;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Lambert {
    pub albedo: Rgb,
}

impl Brdf for Lambert {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if both_above(i, o) { self.albedo.max(Vec3::ZERO) * FRAC_1_PI } else { Vec3::ZERO }
    }
}
