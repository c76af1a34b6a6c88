//! What a point of a simulated capture measures: not the true BRDF at its
//! centre but the mean over its footprint, the sample-plane points of the
//! sensor pixels its value is read from (the demosaic's neighbours and the
//! bilinear read's four pixels, about 1 mm across at the balanced preset).
//! Where the material varies within that footprint (satin's weave cells
//! are 2.5 mm), no fit of the point's samples can reach the centre's BRDF;
//! `refl eval` scores against both truths so that the camera's resolution
//! and the fitter's error are told apart, and `refl bench budget` reads
//! one row's synthetic samples through the footprint ([`mean_at`]).
//!
//! The footprint is located through the capture's camera as the fitter
//! located its points (`capture.json`'s geometry, the calibrated one), so
//! a calibration error moves the footprint with the point and stays out of
//! this figure, as it stays out of the centre truth (`Material`'s point
//! positions).

use std::sync::Arc;

use brdf::ndf::{Coverage, NdfGrid, NdfTable};
use brdf::{Brdf, Rgb};
use frame::Layout;
use glam::{Vec2, Vec3};
use material::{Material, PointMaterial, SvBrdf};
use setup::{CameraModel, SampleArea};

/// The sample-plane points a value read at `pos` comes from, through the
/// camera `cam` whose sensor has `layout`, each with its raw sample's colour
/// and its share of the value (luminance-weighted, as the fitter's scalar
/// specular; `frame::Layout::sample_weights`). Only the taps on the
/// `sample` are kept: a point whose read reaches beyond it is one the
/// fitter does not measure (`fit::context::PIXEL_REACH`), and beyond it the
/// truth is not the sample's. `None` outside the frame or for a capture
/// without a sensor layout.
pub fn taps(
    cam: &CameraModel,
    layout: Option<Layout>,
    sample: &SampleArea,
    pos: Vec2,
) -> Option<Vec<(Vec2, usize, f32)>> {
    let px = cam.project(pos.extend(0.0))?;
    let taps = layout?.sample_weights(cam.width, cam.height, px.x, px.y, fit::partial::LUMA)?;
    Some(
        taps.iter()
            .filter_map(|t| {
                let q = cam.pixel_to(Vec2::new(t.x as f32 + 0.5, t.y as f32 + 0.5), Vec3::ZERO, Vec3::Z)?.truncate();
                sample.contains(q).then_some((q, t.colour, t.b))
            })
            .collect(),
    )
}

/// The NDF the point at `pos` measures, normalised over the hemisphere:
/// the true NDFs of its footprint, each weighted by its share of the value
/// and its specular albedo in its pixel's colour. It leaves out that
/// masking and Fresnel differ between the footprint's points (they do not
/// where only the lobes vary, as in every built-in sample); `None` where
/// [`taps`] is, or where the footprint has no specular.
pub fn ndf(
    cam: &CameraModel,
    layout: Option<Layout>,
    sample: &SampleArea,
    truth: &dyn SvBrdf,
    pos: Vec2,
    grid: NdfGrid,
) -> Option<NdfTable> {
    let mut values = vec![0.0f64; grid.len()];
    let mut total = 0.0f64;
    for (q, colour, b) in taps(cam, layout, sample, pos)? {
        let PointMaterial::Microfacet(mf) = truth.at(q) else { continue };
        let w = (b * mf.ks[colour]) as f64;
        if !(w > 0.0) {
            continue;
        }
        let mut d = NdfTable::from_fn(grid, 3, |h| mf.ndf.d(h));
        d.normalize();
        for (v, &x) in values.iter_mut().zip(d.values()) {
            *v += w * x as f64;
        }
        total += w;
    }
    if !(total > 0.0) {
        return None;
    }
    let values = values.into_iter().map(|v| (v / total) as f32).collect();
    NdfTable::from_values(grid, values, Coverage::full(grid.len())).ok()
}

/// The truth as the material's points measure it: at any place of the
/// sample, the mean BRDF of the footprint of the material's point there
/// (the point a material view shows at that place). Rendered against the
/// truth it gives the render error a perfect fit of every point's samples
/// would still have: the resolution floor `refl eval` reports.
pub struct Resolved {
    pub material: Arc<Material>,
    /// The capture's camera and its sensor's layout.
    pub camera: CameraModel,
    pub layout: Option<Layout>,
    pub truth: Arc<dyn SvBrdf>,
}

impl std::fmt::Debug for Resolved {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Resolved").field("truth", &self.truth.name()).finish_non_exhaustive()
    }
}

impl SvBrdf for Resolved {
    fn name(&self) -> &str {
        "truth over each point's footprint"
    }

    fn at(&self, p_mm: Vec2) -> PointMaterial {
        let pos = self.material.point_at(p_mm).map(|p| self.material.grid.position_of(&self.material.sample, p));
        pos.and_then(|pos| mean_at(&self.camera, self.layout, &self.material.sample, self.truth.as_ref(), pos))
            .unwrap_or_else(|| self.truth.at(p_mm))
    }
}

/// The mean BRDF over the footprint of a value read at `pos` ([`taps`]),
/// each tap weighted by its luminance share: what that point measures.
/// `None` where [`taps`] is or has no weight.
pub fn mean_at(
    cam: &CameraModel,
    layout: Option<Layout>,
    sample: &SampleArea,
    truth: &dyn SvBrdf,
    pos: Vec2,
) -> Option<PointMaterial> {
    let taps = taps(cam, layout, sample, pos)?;
    let total: f32 = taps.iter().map(|t| t.2).sum();
    if !(total > 0.0) {
        return None;
    }
    let parts = taps.iter().map(|&(q, _, b)| (b / total, truth.at(q))).collect();
    Some(PointMaterial::Model(Arc::new(Mean { parts })))
}

/// A weighted mean of BRDFs.
struct Mean {
    parts: Vec<(f32, PointMaterial)>,
}

impl Brdf for Mean {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        self.parts.iter().map(|(w, b)| b.eval(i, o) * *w).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdf::fresnel::Fresnel;
    use brdf::ndf::{Beckmann, Ndf};

    const GRID: NdfGrid = NdfGrid { n_theta: 16, n_phi: 48 };

    fn camera() -> CameraModel {
        setup::RigGeometry::default().camera
    }

    fn area() -> SampleArea {
        setup::RigGeometry::default().sample
    }

    fn bayer() -> Option<Layout> {
        Some(Layout::Bayer { pattern: frame::BayerPattern::Rggb })
    }

    fn lobe(alpha_x: f32, alpha_y: f32, angle: f32) -> PointMaterial {
        let ndf: Arc<dyn Ndf> = Arc::new(Beckmann::new(alpha_x, alpha_y, angle));
        PointMaterial::microfacet(Vec3::splat(0.2), Vec3::splat(0.8), ndf, Fresnel::Dielectric { eta: 1.5 })
    }

    /// One lobe left of `x = edge`, another right of it.
    struct Halves {
        edge: f32,
    }

    impl SvBrdf for Halves {
        fn name(&self) -> &str {
            "halves"
        }
        fn at(&self, p: Vec2) -> PointMaterial {
            if p.x < self.edge { lobe(0.1, 0.35, 0.0) } else { lobe(0.1, 0.35, std::f32::consts::FRAC_PI_2) }
        }
    }

    fn table(m: &PointMaterial) -> NdfTable {
        let mut t = NdfTable::from_fn(GRID, 3, |h| m.ndf().unwrap().d(h));
        t.normalize();
        t
    }

    /// The read's taps sit around the point, within its 4 x 4 window of
    /// sensor pixels: their weighted centre within a quarter pixel of it
    /// (the bilinear read's weights are centred on the point, the
    /// demosaic's neighbours symmetric about theirs up to one pixel's
    /// parity) and none further than the window's corner.
    #[test]
    fn taps_surround_the_point_within_the_reads_window() {
        let cam = camera();
        for pos in [Vec2::ZERO, Vec2::new(20.3, -11.7), Vec2::new(-31.0, 27.2)] {
            let taps = taps(&cam, bayer(), &area(), pos).unwrap();
            let px = cam.project(pos.extend(0.0)).unwrap();
            let size = |d: Vec2| {
                let a = cam.pixel_to(px, Vec3::ZERO, Vec3::Z).unwrap();
                let b = cam.pixel_to(px + d, Vec3::ZERO, Vec3::Z).unwrap();
                (b - a).length()
            };
            let pixel = size(Vec2::X).max(size(Vec2::Y));
            let total: f32 = taps.iter().map(|t| t.2).sum();
            assert!((total - 1.0).abs() < 1e-4, "the shares sum to one luminance: {total}");
            let centre = taps.iter().map(|t| t.0 * t.2).sum::<Vec2>() / total;
            assert!((centre - pos).length() < 0.25 * pixel, "{pos}: centre {centre}, pixel {pixel} mm");
            for t in &taps {
                assert!((t.0 - pos).length() <= 2.0 * 2f32.sqrt() * pixel * 1.05, "{pos}: tap at {}", t.0);
            }
        }
    }

    /// A material that does not vary measures its own NDF and BRDF.
    #[test]
    fn a_uniform_material_is_its_own_footprint_truth() {
        struct Uniform;
        impl SvBrdf for Uniform {
            fn name(&self) -> &str {
                "uniform"
            }
            fn at(&self, _: Vec2) -> PointMaterial {
                lobe(0.12, 0.3, 0.4)
            }
        }
        let pos = Vec2::new(5.0, -3.0);
        let want = table(&Uniform.at(pos));
        let got = ndf(&camera(), bayer(), &area(), &Uniform, pos, GRID).unwrap();
        for (a, b) in got.values().iter().zip(want.values()) {
            assert!((a - b).abs() <= 1e-5 * b.max(1e-3), "{a} against {b}");
        }
    }

    /// On an edge between two lobes the point measures the mean of both,
    /// weighted by the shares of the taps on either side; away from the
    /// edge, its own side's alone.
    #[test]
    fn a_footprint_across_an_edge_measures_the_weighted_mean_of_both_sides() {
        let m = Halves { edge: 0.0 };
        let (left, right) = (table(&m.at(Vec2::new(-1.0, 0.0))), table(&m.at(Vec2::new(1.0, 0.0))));
        let pos = Vec2::new(0.0, 4.0);
        let taps = taps(&camera(), bayer(), &area(), pos).unwrap();
        let w_left: f32 =
            taps.iter().filter(|t| t.0.x < 0.0).map(|t| t.2).sum::<f32>() / taps.iter().map(|t| t.2).sum::<f32>();
        assert!(w_left > 0.2 && w_left < 0.8, "the read straddles the edge: {w_left}");
        let got = ndf(&camera(), bayer(), &area(), &m, pos, GRID).unwrap();
        let mut differ = 0.0f32;
        for ((g, l), r) in got.values().iter().zip(left.values()).zip(right.values()) {
            let want = w_left * l + (1.0 - w_left) * r;
            assert!((g - want).abs() <= 1e-4 * want.max(1e-2), "{g} against {want}");
            differ = differ.max((l - r).abs());
        }
        assert!(differ > 1.0, "the two lobes differ");
        let far = ndf(&camera(), bayer(), &area(), &m, Vec2::new(-10.0, 4.0), GRID).unwrap();
        for (g, l) in far.values().iter().zip(left.values()) {
            assert!((g - l).abs() <= 1e-5 * l.max(1e-3));
        }
    }
}
