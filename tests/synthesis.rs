//! Microfacet synthesis against ground truth on simulated captures.
//!
//! The error is the relative L2 distance between recovered and true NDF
//! tables in the table's cosine measure, pooled over every point with
//! specular (as `refl eval` reports it), split into the cells the partial
//! tables observed and the cells they did not (which synthesis supplies).
//! The partial tables are empty outside their coverage, so their error
//! there is 1.
//!
//! - `satin` varies in orientation across the sample, so other points'
//!   rotated NDFs hold what one view misses: synthesis must cut the
//!   missing-region error by at least 15% (measured: 1.00 to 0.75 at this
//!   size) and lower the whole-hemisphere error.
//! - `brushed-metal` has one narrow lobe whose observed part this small,
//!   sparse capture resolves poorly (observed-region error 0.72), so the
//!   examples synthesis draws on are poor too: measured 1.00 to 0.88 in the
//!   missing region. The test holds the line at a 10% cut and a lower
//!   whole-hemisphere error; a denser capture is what improves it.
//! - `ward` has one orientation everywhere; the only help is a point's
//!   neighbours turned by 180 degrees (the lobe is centrally symmetric),
//!   and synthesis must not make the error worse by more than 2%.
//! - The accelerated search against brute force on the same small input:
//!   its missing-region error within 10% of brute force's, and both well
//!   below the partial tables'.

#[path = "support/simfit.rs"]
mod simfit;

use brdf::ndf::{MaskingOperator, NdfTable, TableSet};
use fit::FitSettings;
use fit::synth::{SearchMode, SynthSettings, synthesize};
use simfit::{Fitted, Scenario, run, true_table};

fn scenario(name: &str) -> Scenario {
    Scenario {
        material: sim::materials::builtin(name).unwrap(),
        camera_px: 128,
        grid: 20,
        steps: 48,
        led_stride: 1,
        exposures_us: vec![20_000],
        seed: 5,
    }
}

/// Pooled relative L2 error of `tables` against the truth.
struct NdfError {
    /// Over the cells the partial tables observed.
    observed: f64,
    /// Over the cells they did not: what synthesis has to supply.
    missing: f64,
    /// Over the whole hemisphere.
    full: f64,
}

fn ndf_error(s: &Scenario, f: &Fitted, tables: &TableSet) -> NdfError {
    let add = |acc: &mut (f64, f64), v: Option<(f64, f64)>| {
        let (n, d) = v.unwrap_or((0.0, 0.0));
        acc.0 += n;
        acc.1 += d;
    };
    let (mut obs, mut miss, mut full) = ((0.0, 0.0), (0.0, 0.0), (0.0, 0.0));
    for p in 0..f.maps.len() {
        if f.maps.flags[p] & fit::point_flag::NO_SPECULAR != 0 {
            continue;
        }
        let Some(t) = true_table(s.material.as_ref(), f, p) else { continue };
        let est = tables.get(p);
        let seen = f.maps.tables.get(p);
        add(&mut obs, est.l2_sums(&t, |c| seen.coverage().get(c)));
        add(&mut miss, est.l2_sums(&t, |c| !seen.coverage().get(c)));
        add(&mut full, est.l2_sums(&t, |_| true));
    }
    let rel = |(n, d): (f64, f64)| (n / d).sqrt();
    NdfError { observed: rel(obs), missing: rel(miss), full: rel(full) }
}

fn eligible(f: &Fitted) -> Vec<bool> {
    f.maps.flags.iter().map(|fl| fl & fit::point_flag::NO_SPECULAR == 0).collect()
}

/// The synthesized tables after the refit with the completed NDF.
fn synthesized(f: &Fitted, settings: &SynthSettings) -> TableSet {
    let mut maps = f.maps.clone();
    let op = MaskingOperator::new(f.settings.grid);
    fit::pipeline::synthesis_stage(&f.ctx, &f.store, &mut maps, settings, &f.settings, &op);
    maps.tables
}

fn small_settings(mode: SearchMode) -> SynthSettings {
    SynthSettings { mode, clusters: 24, ..SynthSettings::default() }
}

fn reduction(name: &str) -> (NdfError, NdfError) {
    let s = scenario(name);
    let f = run(&s, FitSettings::default());
    let p = ndf_error(&s, &f, &f.maps.tables);
    let q = ndf_error(&s, &f, &synthesized(&f, &small_settings(SearchMode::Accelerated)));
    eprintln!(
        "{name}: NDF error (observed, missing, full): partial {:.4} {:.4} {:.4}; synthesized {:.4} {:.4} {:.4}",
        p.observed, p.missing, p.full, q.observed, q.missing, q.full
    );
    (p, q)
}

/// Synthesis cuts `name`'s missing-region error by at least `min_cut` and
/// lowers its whole-hemisphere error.
fn assert_completes(name: &str, min_cut: f64) {
    let (p, q) = reduction(name);
    assert!(
        q.missing < (1.0 - min_cut) * p.missing,
        "{name} missing region: synthesized {:.4} vs partial {:.4}",
        q.missing,
        p.missing
    );
    assert!(q.full < p.full, "{name}: synthesized {:.4} vs partial {:.4}", q.full, p.full);
}

#[test]
fn synthesis_completes_satin() {
    assert_completes("satin", 0.15);
}

#[test]
fn synthesis_completes_brushed_metal() {
    assert_completes("brushed-metal", 0.10);
}

#[test]
fn synthesis_does_not_harm_a_single_orientation() {
    let (p, q) = reduction("ward");
    assert!(q.full <= 1.02 * p.full, "ward: synthesized {:.4} vs partial {:.4}", q.full, p.full);
}

/// On a single Beckmann lobe whose long flank no point observes (every
/// point of `ward` sees it from the same side, so no match covers it), the
/// tail, a lobe of the truth's own form fitted to the rest, must restore
/// most of that flank: the missing region's error at least halves against
/// synthesis without it, and the hemisphere's falls.
#[test]
fn the_tail_restores_what_no_match_covers() {
    let s = scenario("ward");
    let f = run(&s, FitSettings::default());
    let with = ndf_error(&s, &f, &synthesized(&f, &small_settings(SearchMode::Accelerated)));
    let without =
        ndf_error(&s, &f, &synthesized(&f, &SynthSettings { tail: false, ..small_settings(SearchMode::Accelerated) }));
    eprintln!(
        "ward: NDF error (missing, full): with the tail {:.4} {:.4}; without {:.4} {:.4}",
        with.missing, with.full, without.missing, without.full
    );
    assert!(with.missing < 0.5 * without.missing, "missing region: {:.4} vs {:.4}", with.missing, without.missing);
    assert!(with.full < without.full, "hemisphere: {:.4} vs {:.4}", with.full, without.full);
}

#[test]
fn accelerated_search_agrees_with_brute_force() {
    let s = Scenario { grid: 14, ..scenario("satin") };
    let f = run(&s, FitSettings::default());
    let p = ndf_error(&s, &f, &f.maps.tables);
    // The searches alone: the tail would cover every cell either way.
    let search = |mode| SynthSettings { tail: false, ..small_settings(mode) };
    let brute = synthesized(&f, &search(SearchMode::BruteForce));
    let fast = synthesized(&f, &search(SearchMode::Accelerated));
    let eb = ndf_error(&s, &f, &brute);
    let ea = ndf_error(&s, &f, &fast);
    eprintln!("missing region: partial {:.4}, brute force {:.4}, accelerated {:.4}", p.missing, eb.missing, ea.missing);
    assert!(eb.missing < 0.85 * p.missing, "brute force {:.4} vs partial {:.4}", eb.missing, p.missing);
    assert!(ea.missing < 1.10 * eb.missing, "accelerated {:.4} vs brute force {:.4}", ea.missing, eb.missing);
    // The two complete the same cells for most points.
    let same = (0..brute.len())
        .filter(|&p| {
            let (a, b) = (brute.get(p), fast.get(p));
            let (ca, cb) = (a.coverage().count(), b.coverage().count());
            ca.abs_diff(cb) as f32 <= 0.1 * ca.max(1) as f32
        })
        .count();
    assert!(same as f32 >= 0.8 * brute.len() as f32, "{same} of {} points covered alike", brute.len());
}

/// A table with nothing observed stays empty (and finite) through synthesis.
#[test]
fn points_without_specular_are_left_alone() {
    let s = Scenario { grid: 8, ..scenario("satin") };
    let f = run(&s, FitSettings::default());
    let mut el = eligible(&f);
    el[0] = false;
    let out = synthesize(&f.maps.tables, &el, &small_settings(SearchMode::Accelerated));
    assert_eq!(out.mass_factor[0], 1.0);
    let t: NdfTable = out.tables.get(0);
    assert_eq!(t.values(), f.maps.tables.get(0).values());
    assert!(out.tables.get(1).values().iter().all(|v| v.is_finite()));
}
