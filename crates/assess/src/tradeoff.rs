//! `refl tradeoff SAMPLE --out DIR`: the speed/accuracy trade-off, measured.
//!
//! Each setting (a quality preset, possibly with a knob changed) is a full
//! simulated capture by the real `capture` binary in its own process (so
//! its peak memory is its own), then `refl eval`'s scoring. The rows go to
//! `tradeoff.json`; `tradeoff.png` plots what the lab pays in time against
//! the measured model's render error, with the Pareto front (no other
//! setting is both faster and more accurate) drawn through its points.
//!
//! The time is the rig's: the least time the real rig takes the plan in
//! (every frame at the rig file's frame rate, every move at its gantry's
//! speed, `CapturePlan::physical_seconds`), plus the fit's time after the
//! last frame. The simulator's own wall time, which says nothing about the
//! rig, is kept beside it (`sim_capture_seconds`).

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, anyhow, bail};
use serde::{Deserialize, Serialize};

use crate::Progress;
use crate::eval::{EvalOptions, evaluate};

/// The settings `refl tradeoff` knows: name, preset, extra `capture` args.
pub const SETTINGS: &[(&str, &str, &[&str])] = &[
    ("fast", "fast", &[]),
    ("fast-16-steps", "fast", &["--steps", "16"]),
    ("fast-all-leds", "fast", &["--led-stride", "1"]),
    ("balanced-no-synthesis", "balanced", &["--no-synthesis"]),
    ("balanced-per-point", "balanced", &["--no-pooling"]),
    ("balanced", "balanced", &[]),
    ("balanced-ndf-24", "balanced", &["--ndf-theta", "24"]),
    ("best", "best", &[]),
];

/// The default sweep: every setting (`best` alone takes several minutes).
pub const DEFAULT_SETTINGS: &str =
    "fast,fast-16-steps,fast-all-leds,balanced-no-synthesis,balanced-per-point,balanced,balanced-ndf-24,best";

/// Render errors closer than this (relative) are not told apart when
/// drawing the front. One setting's error moves with the simulator's noise
/// seed: `bash scripts/seed-spread.sh satin 4 fast` measured standard
/// deviations of 0.1% to 0.9% per model; two errors within 2% are within
/// about two standard deviations of their difference at the largest
/// spread, so a setting that is slower for less than that is not better.
pub const ERROR_RESOLUTION: f64 = 0.02;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub setting: String,
    pub quality: String,
    pub args: Vec<String>,
    /// The rig's physical time for the plan (frames at its frame rate,
    /// moves and settling).
    pub capture_seconds: f64,
    pub fit_seconds: f64,
    /// `capture_seconds + fit_seconds`: what the lab waits.
    pub total_seconds: f64,
    /// The simulated capture's wall time (the simulator's speed, not the rig's).
    #[serde(default)]
    pub sim_capture_seconds: f64,
    pub peak_memory_mb: Option<f64>,
    /// The measured model's (synthesized, else partial) render error.
    pub render_rel_rmse: Option<f64>,
    pub ndf_rel_l2_full: Option<f64>,
    /// Every model's render error.
    pub models: serde_json::Value,
    pub holdout_rel_rmse: Option<f64>,
    pub pareto: bool,
}

fn capture_exe() -> Result<PathBuf> {
    let me = std::env::current_exe().context("cannot find this executable")?;
    let p = me.with_file_name("capture");
    if !p.is_file() {
        bail!("{} not found: build both binaries (cargo build --release)", p.display());
    }
    Ok(p)
}

fn seconds(report: &crate::report::Report, key: &str) -> f64 {
    report.timings.get(key).copied().unwrap_or(0.0)
}

/// Run the sweep.
pub fn run(sample: &str, out: &Path, settings: &str, rep: &mut dyn Progress) -> Result<Vec<Row>> {
    let chosen: Vec<&(&str, &str, &[&str])> = settings
        .split(',')
        .map(|n| {
            SETTINGS.iter().find(|(name, _, _)| *name == n.trim()).ok_or_else(|| {
                anyhow!(
                    "unknown setting '{n}': known are {}",
                    SETTINGS.iter().map(|s| s.0).collect::<Vec<_>>().join(", ")
                )
            })
        })
        .collect::<Result<_>>()?;
    if out.join("tradeoff.json").exists() {
        bail!("{} already holds a trade-off; choose another --out", out.display());
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let exe = capture_exe()?;
    // The rig the captures run on: the one `capture` loads without --rig.
    let (rig, _) = config::RigFile::load(None)?;
    let fps = rig.camera.as_ref().map_or(rig.sim.fps, |c| c.fps);
    let mut rows = Vec::new();
    for (k, (name, quality, args)) in chosen.iter().enumerate() {
        rep.stage("tradeoff", format!("{}/{}: {name}", k + 1, chosen.len()));
        let dir = out.join(name);
        let status = Command::new(&exe)
            .args(["--sample", sample, "--quality", quality, "--no-daemon", "--out"])
            .arg(&dir)
            .args(*args)
            .stdout(std::process::Stdio::null())
            .status()
            .with_context(|| format!("cannot run {}", exe.display()))?;
        if !status.success() {
            bail!("the capture for setting {name} failed ({status}); see above");
        }
        let report = crate::report::read(&dir)?;
        let ev = evaluate(&dir, &EvalOptions { render_px: 96, ..Default::default() }, rep)?;
        let measured = ev.models.get("synthesized").or_else(|| ev.models.get("partial"));
        let info = store::CaptureDir::read_info(&dir)?;
        let capture_seconds = info.plan.physical_seconds(&info.geometry, fps);
        let fit_seconds = seconds(&report, "fit_total_after_capture_s");
        rows.push(Row {
            setting: name.to_string(),
            quality: quality.to_string(),
            args: args.iter().map(|a| a.to_string()).collect(),
            capture_seconds,
            fit_seconds,
            total_seconds: capture_seconds + fit_seconds,
            sim_capture_seconds: seconds(&report, "capture_s"),
            peak_memory_mb: report.peak_memory_mb,
            render_rel_rmse: measured.and_then(|m| m.render_rel_rmse),
            ndf_rel_l2_full: measured.and_then(|m| m.ndf_rel_l2_full),
            models: serde_json::to_value(
                ev.models
                    .iter()
                    .map(|(k, v)| (k.clone(), v.render_rel_rmse))
                    .collect::<std::collections::BTreeMap<_, _>>(),
            )?,
            holdout_rel_rmse: ev
                .holdout
                .get("synthesized")
                .or_else(|| ev.holdout.get("partial"))
                .and_then(|h| h.frame_rel_rmse),
            pareto: false,
        });
    }
    mark_pareto(&mut rows);
    std::fs::write(out.join("tradeoff.json"), serde_json::to_vec_pretty(&rows)?)?;
    chart(&out.join("tradeoff.png"), &rows)?;
    Ok(rows)
}

/// A row is on the front unless another dominates it: is no slower, has
/// an error no more than [`ERROR_RESOLUTION`] above its own, and is either
/// faster or more accurate by more than the resolution.
pub fn mark_pareto(rows: &mut [Row]) {
    let pts: Vec<(f64, f64)> =
        rows.iter().map(|r| (r.total_seconds, r.render_rel_rmse.unwrap_or(f64::INFINITY))).collect();
    let k = 1.0 + ERROR_RESOLUTION;
    let dominates = |(t2, e2): (f64, f64), (t, e): (f64, f64)| t2 <= t && e2 <= e * k && (t2 < t || e2 * k < e);
    for (i, r) in rows.iter_mut().enumerate() {
        r.pareto = pts[i].1.is_finite() && !pts.iter().enumerate().any(|(j, &p)| j != i && dominates(p, pts[i]));
    }
}

/// Draw the chart: time (log scale) against error, points labelled, the
/// front joined by a line.
pub fn chart(path: &Path, rows: &[Row]) -> Result<()> {
    let (w, h) = (900u32, 560u32);
    let (left, right, top, bottom) = (80.0f64, 40.0f64, 50.0f64, 70.0f64);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let pts: Vec<(f64, f64, &Row)> =
        rows.iter().filter_map(|r| r.render_rel_rmse.map(|e| (r.total_seconds.max(1e-3), e, r))).collect();
    if pts.is_empty() {
        bail!("no setting has an error to plot");
    }
    let (mut t0, mut t1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (mut e0, mut e1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    t0 = (t0 / 1.5).log10();
    t1 = (t1 * 1.5).log10();
    let pad = ((e1 - e0) * 0.15).max(0.01);
    e0 = (e0 - pad).max(0.0);
    e1 += pad;
    let x = |t: f64| left + (t.log10() - t0) / (t1 - t0) * (w as f64 - left - right);
    let y = |e: f64| top + (e1 - e) / (e1 - e0) * (h as f64 - top - bottom);
    let put = |buf: &mut [u8], px: i64, py: i64, c: [u8; 3]| {
        if px >= 0 && py >= 0 && (px as u32) < w && (py as u32) < h {
            let k = ((py as u32 * w + px as u32) * 3) as usize;
            buf[k..k + 3].copy_from_slice(&c);
        }
    };
    let line = |buf: &mut [u8], a: (f64, f64), b: (f64, f64), c: [u8; 3]| {
        let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) as usize).max(1);
        for s in 0..=n {
            let f = s as f64 / n as f64;
            put(buf, (a.0 + (b.0 - a.0) * f).round() as i64, (a.1 + (b.1 - a.1) * f).round() as i64, c);
        }
    };
    let (xa, xb, ya, yb) = (left, w as f64 - right, top, h as f64 - bottom);
    line(&mut buf, (xa, yb), (xb, yb), [0, 0, 0]);
    line(&mut buf, (xa, ya), (xa, yb), [0, 0, 0]);
    // Text is drawn light-on-dark by draw_text; draw it on an inverted copy.
    let mut text = vec![0u8; buf.len()];
    let label = |text: &mut [u8], px: f64, py: f64, size: f32, s: &str| {
        render::output::draw_text(text, w, h, px as i32, py as i32, size, s);
    };
    // Time ticks at 1, 2, 5 x 10^k seconds.
    for k in -1..5 {
        for m in [1.0, 2.0, 5.0] {
            let t = m * 10f64.powi(k);
            if t.log10() < t0 || t.log10() > t1 {
                continue;
            }
            let px = x(t);
            line(&mut buf, (px, yb), (px, yb + 6.0), [0, 0, 0]);
            label(&mut text, px - 10.0, yb + 8.0, 15.0, &format!("{t}"));
        }
    }
    for k in 0..=5 {
        let e = e0 + (e1 - e0) * k as f64 / 5.0;
        let py = y(e);
        line(&mut buf, (xa - 6.0, py), (xa, py), [0, 0, 0]);
        label(&mut text, 8.0, py - 9.0, 15.0, &format!("{e:.3}"));
    }
    label(&mut text, w as f64 / 2.0 - 190.0, h as f64 - 32.0, 17.0, "rig capture time + fit time (s, log scale)");
    label(&mut text, 8.0, 10.0, 17.0, "render error of the measured model (relative RMSE); line: Pareto front");
    let mut front: Vec<&(f64, f64, &Row)> = pts.iter().filter(|p| p.2.pareto).collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    for pair in front.windows(2) {
        line(&mut buf, (x(pair[0].0), y(pair[0].1)), (x(pair[1].0), y(pair[1].1)), [220, 60, 40]);
    }
    // Labels alternate above and below the points (in time order), so
    // neighbours do not overwrite each other.
    let mut order: Vec<usize> = (0..pts.len()).collect();
    order.sort_by(|&a, &b| pts[a].0.total_cmp(&pts[b].0));
    for (k, &idx) in order.iter().enumerate() {
        let (t, e, r) = &pts[idx];
        let (px, py) = (x(*t), y(*e));
        let c = if r.pareto { [220, 60, 40] } else { [40, 90, 200] };
        for dy in -4..=4 {
            for dx in -4..=4 {
                put(&mut buf, px as i64 + dx, py as i64 + dy, c);
            }
        }
        label(&mut text, px + 8.0, if k % 2 == 0 { py - 22.0 } else { py + 6.0 }, 15.0, &r.setting);
    }
    // Composite the text in black.
    for (b, t) in buf.iter_mut().zip(&text) {
        *b = ((*b as u16 * (255 - *t as u16)) / 255) as u8;
    }
    image::save_buffer(path, &buf, w, h, image::ExtendedColorType::Rgb8)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Redraw `tradeoff.png` from the `tradeoff.json` in `out`.
pub fn replot(out: &Path) -> Result<Vec<Row>> {
    let p = out.join("tradeoff.json");
    let rows: Vec<Row> =
        serde_json::from_slice(&std::fs::read(&p).with_context(|| format!("cannot read {}", p.display()))?)
            .with_context(|| format!("{} is not a trade-off table", p.display()))?;
    chart(&out.join("tradeoff.png"), &rows)?;
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(name: &str, t: f64, e: f64) -> Row {
        Row {
            setting: name.into(),
            quality: "fast".into(),
            args: Vec::new(),
            capture_seconds: t,
            fit_seconds: 0.0,
            total_seconds: t,
            sim_capture_seconds: 0.0,
            peak_memory_mb: None,
            render_rel_rmse: Some(e),
            ndf_rel_l2_full: None,
            models: serde_json::Value::Null,
            holdout_rel_rmse: None,
            pareto: false,
        }
    }

    #[test]
    fn the_front_holds_exactly_the_undominated_settings() {
        let mut rows = vec![
            row("a", 1.0, 0.3),
            row("b", 2.0, 0.2),
            row("c", 3.0, 0.25),
            row("d", 4.0, 0.1),
            row("e", 4.0, 0.1),
            // Slower than d for an error better by less than the resolution.
            row("f", 5.0, 0.1 / (1.0 + ERROR_RESOLUTION / 2.0)),
            // Slower than d and better by more than the resolution.
            row("g", 6.0, 0.1 / (1.0 + 2.0 * ERROR_RESOLUTION)),
        ];
        mark_pareto(&mut rows);
        let front: Vec<&str> = rows.iter().filter(|r| r.pareto).map(|r| r.setting.as_str()).collect();
        // c is beaten by b; d and e tie (neither strictly better), both
        // stay; f is not better than d by a difference that can be told
        // apart; g is.
        assert_eq!(front, ["a", "b", "d", "e", "g"]);
        let dir = std::env::temp_dir().join(format!("tradeoff-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        chart(&dir.join("t.png"), &rows).unwrap();
        assert!(std::fs::metadata(dir.join("t.png")).unwrap().len() > 1000);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
