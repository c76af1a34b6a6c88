//! The fitter against ground truth on simulated captures.

#[path = "support/simfit.rs"]
mod simfit;

use fit::FitSettings;
use simfit::{Scenario, run, true_table};

#[test]
fn homogeneous_ward_surface() {
    let material = sim::materials::builtin("ward").unwrap();
    let s = Scenario {
        material: material.clone(),
        camera_px: 96,
        grid: 12,
        steps: 48,
        led_stride: 1,
        exposures_us: vec![20_000, 2_500],
        seed: 3,
    };
    let f = run(&s, FitSettings::default());
    eprintln!("census {:?}", f.store.census());
    for q in (0..f.store.n_lights()).step_by(97) {
        eprintln!("q {q}: {:?} geo {:?}", f.store.get(q, 66), f.ctx.sample(66, q));
    }
    {
        let t = true_table(material.as_ref(), &f, 66).unwrap();
        let est = f.maps.tables.get(66);
        let g = f.settings.grid;
        let argmax = |v: &[f32]| v.iter().enumerate().fold((0, 0.0f32), |a, (i, &x)| if x > a.1 { (i, x) } else { a });
        let (ie, ve) = argmax(est.values());
        let (it, vt) = argmax(t.values());
        eprintln!(
            "est max cell ({}, {}) = {ve}; true max cell ({}, {}) = {vt}",
            ie / g.n_phi as usize,
            ie % g.n_phi as usize,
            it / g.n_phi as usize,
            it % g.n_phi as usize
        );
        let mass_in: f32 = (0..g.len())
            .filter(|&c| est.coverage().get(c))
            .map(|c| t.values()[c] * g.cos_measure(c / g.n_phi as usize))
            .sum();
        eprintln!("true mass inside coverage {mass_in}");
        for tt in 0..12 {
            let row: Vec<String> =
                (0..96).step_by(8).map(|p| format!("{:6.2}/{:6.2}", est.at(tt, p), t.at(tt, p))).collect();
            eprintln!("ring {tt}: {}", row.join(" "));
        }
    }
    let ps = fit::points::gather(&f.ctx, &f.store, 66, &f.settings);
    eprintln!("gathered {} lit {}", ps.samples.len(), ps.lit);
    let mut th: Vec<(f32, glam::Vec3, [f32; 3])> = ps
        .samples
        .iter()
        .map(|x| {
            let h = (x.i + ps.o).normalize();
            (h.z.acos().to_degrees(), x.i, x.rho)
        })
        .collect();
    th.sort_by(|a, b| a.0.total_cmp(&b.0));
    for t in th.iter().take(8) {
        eprintln!("theta_h {:.2} i {:?} rho {:?}", t.0, t.1, t.2);
    }
    eprintln!("o {:?} pos {:?}", ps.o, f.ctx.positions[66]);
    for p in [0usize, 30, 66, 77, 100, 143] {
        let truth = material.at(f.ctx.positions[p].truncate());
        let t = true_table(material.as_ref(), &f, p).unwrap();
        let est = f.maps.tables.get(p);
        let obs = est.coverage().clone();
        let e_obs = est.rel_l2(&t, Some(&obs));
        eprintln!(
            "p {p}: kd {:?} (true {:?}) ks {:?} eta {} flags {:#x} ndf err obs {:?} cov {:.2} stats {:?}",
            f.maps.kd[p],
            truth.kd(),
            f.maps.ks[p],
            f.maps.eta[p],
            f.maps.flags[p],
            e_obs,
            f.maps.stats[p].coverage,
            f.maps.stats[p]
        );
    }
}
