//! `refl inspect`: what a stored material holds, in numbers: its grid,
//! NDF kind, point flags, model choice and the spread of every fitted
//! parameter (5th, 50th and 95th percentiles over the points the camera
//! measured; the others hold no fit).

use std::path::Path;

use anyhow::Context;
use material::{Choice, Material};
use serde::Serialize;

#[derive(Debug, Serialize)]
pub struct Spread {
    pub name: String,
    pub p05: f32,
    pub p50: f32,
    pub p95: f32,
}

#[derive(Debug, Serialize)]
pub struct ModelSummary {
    pub model: String,
    pub fit_seconds: f64,
    pub params: Vec<Spread>,
}

#[derive(Debug, Serialize)]
pub struct Inspection {
    pub name: String,
    pub points: usize,
    pub grid: [u32; 2],
    pub ndf: Option<String>,
    /// Points carrying each fit flag.
    pub flags: Vec<(String, usize)>,
    /// Measured points per model class, when the material has a choice map.
    pub choice: Vec<(String, usize)>,
    /// Why: the evidence per region, as the fit recorded it.
    pub choice_evidence: Option<fit::select::SelectionSummary>,
    pub kd: Vec<Spread>,
    pub ks: Vec<Spread>,
    pub eta: Spread,
    pub models: Vec<ModelSummary>,
}

fn spread(name: &str, values: impl Iterator<Item = f32>) -> Spread {
    let mut v: Vec<f32> = values.filter(|x| x.is_finite()).collect();
    v.sort_by(f32::total_cmp);
    let at = |q: f32| if v.is_empty() { f32::NAN } else { v[((v.len() - 1) as f32 * q).round() as usize] };
    Spread { name: name.to_string(), p05: at(0.05), p50: at(0.5), p95: at(0.95) }
}

pub fn inspect(dir: &Path) -> anyhow::Result<Inspection> {
    let m: Material = material::io::read(dir).with_context(|| format!("reading the material in {}", dir.display()))?;
    let n = m.n_points();
    let measured: Vec<usize> = (0..n).filter(|&p| m.is_measured(p)).collect();
    let flags = fit::partial::point_flag::NAMES
        .iter()
        .map(|&(bit, name)| (name.to_string(), m.flags.iter().filter(|&&f| f & bit != 0).count()))
        .filter(|(_, c)| *c > 0)
        .collect();
    let choice = match &m.choice {
        Some(c) => [
            ("diffuse".to_string(), Choice::Diffuse),
            (c.isotropic_model.name().to_string(), Choice::Isotropic),
            (c.anisotropic_model.name().to_string(), Choice::Anisotropic),
            ("tabulated".to_string(), Choice::Tabulated),
        ]
        .into_iter()
        .map(|(name, k)| (name, measured.iter().filter(|&&p| c.choice.get(p) == Some(&k)).count()))
        .collect(),
        None => Vec::new(),
    };
    let rgb = |v: &[[f32; 3]], prefix: &str| -> Vec<Spread> {
        ["r", "g", "b"]
            .iter()
            .enumerate()
            .map(|(c, ch)| spread(&format!("{prefix}_{ch}"), measured.iter().map(|&p| v[p][c])))
            .collect()
    };
    let models = m
        .models
        .values()
        .map(|mm| {
            let k = mm.model.n_params();
            let params = mm
                .model
                .param_names()
                .iter()
                .enumerate()
                .map(|(j, name)| spread(name, measured.iter().map(|&p| mm.params[p * k + j])))
                .collect();
            ModelSummary { model: mm.model.name().to_string(), fit_seconds: mm.fit_seconds, params }
        })
        .collect();
    Ok(Inspection {
        name: m.name.clone(),
        points: n,
        grid: [m.grid.cols, m.grid.rows],
        ndf: m.ndf.as_ref().map(|_| format!("{:?}", m.ndf_kind).to_lowercase()),
        flags,
        choice,
        choice_evidence: m.provenance.get("model_choice").and_then(|v| serde_json::from_value(v.clone()).ok()),
        kd: rgb(&m.kd, "kd"),
        ks: rgb(&m.ks, "ks"),
        eta: spread("eta", measured.iter().map(|&p| m.eta[p])),
        models,
    })
}

/// Human-readable form.
pub fn print(i: &Inspection) {
    println!(
        "{}: {} points ({} x {}), NDF: {}",
        i.name,
        i.points,
        i.grid[0],
        i.grid[1],
        i.ndf.as_deref().unwrap_or("none")
    );
    if !i.flags.is_empty() {
        let f: Vec<String> = i.flags.iter().map(|(n, c)| format!("{n} {c}")).collect();
        println!("flags: {}", f.join(", "));
    }
    if !i.choice.is_empty() {
        let f: Vec<String> = i.choice.iter().map(|(n, c)| format!("{n} {c}")).collect();
        println!("model choice: {}", f.join(", "));
    }
    if let Some(e) = &i.choice_evidence {
        print_choice(e);
    }
    let row = |s: &Spread| println!("  {:<12} {:>10.4} {:>10.4} {:>10.4}", s.name, s.p05, s.p50, s.p95);
    println!("  {:<12} {:>10} {:>10} {:>10}", "", "p05", "median", "p95");
    i.kd.iter().chain(&i.ks).chain(std::iter::once(&i.eta)).for_each(row);
    for m in &i.models {
        println!("{} (fitted in {:.1} s)", m.model, m.fit_seconds);
        m.params.iter().for_each(row);
    }
}

/// Each region's scores: RMS residual over the noise's RMS on the scored
/// samples, per class, and the one chosen.
fn print_choice(e: &fit::select::SelectionSummary) {
    use fit::select::ScoredOn;
    let on = match e.scored_on {
        ScoredOn::HeldOutSteps => "gantry steps held out of a second fit",
        ScoredOn::FitSamples => "the fit's own samples (too few steps to hold any out; favours the table)",
    };
    let min = fit::select::MIN_SCORED_POINTS;
    println!(
        "  why: per region, RMS residual / noise RMS on {on}; the diffuse class is the point's diffuse albedo alone; a simpler class's score counts the table at the points where it fails as an outlier (stand-ins); the simplest class whose ratio^2 is within its margin of the best's is chosen (margins: 2 deviations of the difference, the noise's or the points' spread, whichever is larger); \"tables\" counts the points of a region that chose a simpler class kept on their tables; a region with fewer than {min} scored points takes the material's class (\"material\" below, marked *)"
    );
    let (iso, aniso) = (e.isotropic_model.as_str(), e.anisotropic_model.as_str());
    println!(
        "  {:>8} {:>7} {:>8} {:>8} {:>11} {:>11} {:>10} {:>27} {:>10} {:>6}  chosen",
        "region", "points", "samples", "diffuse", iso, aniso, "tabulated", "margins", "stand-ins", "tables"
    );
    let names = ["diffuse", iso, aniso, "tabulated"];
    let f = |x: Option<f32>| x.map_or("-".to_string(), |v| format!("{v:.3}"));
    let row = |name: String, r: &fit::select::RegionChoice| {
        let margins: Vec<String> = std::iter::once(r.diffuse_margin).chain(r.margin).map(f).collect();
        println!(
            "  {:>8} {:>7} {:>8} {:>8} {:>11} {:>11} {:>10} {:>27} {:>10} {:>6}  {}{}",
            name,
            r.points,
            r.samples,
            f(r.diffuse_ratio),
            f(r.ratio[0]),
            f(r.ratio[1]),
            f(r.ratio[2]),
            margins.join("/"),
            format!("{}/{}/{}", r.diffuse_stand_ins, r.stand_ins[0], r.stand_ins[1]),
            r.tabulated_points,
            names.get(r.chosen as usize).unwrap_or(&"?"),
            if r.from_material { " *" } else { "" }
        );
    };
    for (k, r) in e.regions.iter().enumerate() {
        row(k.to_string(), r);
    }
    if let Some(m) = &e.material {
        row("material".into(), m);
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_fitter_and_the_format_agree_on_the_unmeasured_bit() {
        assert_eq!(fit::partial::point_flag::OUT_OF_VIEW, material::UNMEASURED);
    }
}
