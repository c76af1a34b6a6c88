//! Turning a finished fit into the capture's outputs: `material/` and
//! `report.json`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use assess::report::{self, Report};
use config::{Overrides, Quality};
use material::Material;
use store::CaptureInfo;
use tokio::sync::watch;

use crate::Interrupted;
use crate::fitjob::FitJob;
use crate::progress::{Event, Reporter};

/// Flag counts over the grid, by name.
pub fn flag_counts(flags: &[u32]) -> std::collections::BTreeMap<String, usize> {
    fit::point_flag::NAMES
        .iter()
        .map(|&(bit, name)| (name.to_string(), flags.iter().filter(|&&f| f & bit != 0).count()))
        .collect()
}

/// Was `e` caused by a full disk? (An ENOSPC anywhere in its chain of
/// sources, or the store's own disk-full error, which replaces it.)
pub fn is_disk_full(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>().is_some_and(|io| io.raw_os_error() == Some(libc::ENOSPC))
            || matches!(c.downcast_ref::<store::StoreError>(), Some(store::StoreError::DiskFull { .. }))
    })
}

/// The same advice a full disk gets during frames, for the fit's outputs:
/// every frame is stored, so nothing is lost and the fit can be run again.
fn disk_full_advice(e: anyhow::Error, root: &Path) -> anyhow::Error {
    if is_disk_full(&e) {
        e.context(format!(
            "the disk holding {0} is full; free some space, then continue with `capture --resume {0}` or \
             `refl fit {0}` (every frame is stored; nothing is lost)",
            root.display()
        ))
    } else {
        e
    }
}

/// A stop request (Ctrl-C, SIGTERM, a cancelled daemon job) as a closure
/// the blocking stages poll.
pub fn stop_requested(stop: &watch::Receiver<bool>) -> impl Fn() -> bool + '_ {
    move || *stop.borrow()
}

/// How often a running fit's progress is reported.
const FIT_PROGRESS_EVERY: std::time::Duration = std::time::Duration::from_millis(500);

/// Wait for the fitter, then write the material and its preview renders.
/// A stop request ends the wait at once (the fitter thread gives up at its
/// next stage) and is returned as [`Interrupted`]; nothing half-written is
/// left (the material is written atomically). A full disk gets the advice
/// of [`disk_full_advice`].
pub async fn finish_fit(
    job: FitJob,
    info: &CaptureInfo,
    q: &Quality,
    root: &Path,
    rep: &mut Reporter,
    report: &mut Report,
    stop: &watch::Receiver<bool>,
) -> Result<PathBuf> {
    let written: Result<PathBuf> = async {
        rep.stage("fit", "per-point NDFs (diffuse, specular, masking, Fresnel)");
        let t = Instant::now();
        let mut watch_stop = stop.clone();
        let progress = job.progress();
        let fit = job.finish_async();
        tokio::pin!(fit);
        // The stages' progress, as often as a person watching wants it.
        let mut tick = tokio::time::interval(FIT_PROGRESS_EVERY);
        let report_fit = |rep: &mut Reporter| {
            if let Some(s) = progress.snapshot() {
                rep.emit(Event::Fit(s));
            }
        };
        let out = loop {
            tokio::select! {
                r = &mut fit => {
                    // Where it ended (every stage's count complete).
                    report_fit(rep);
                    break r?;
                }
                _ = watch_stop.wait_for(|s| *s) => return Err(Interrupted.into()),
                _ = tick.tick() => report_fit(rep),
            }
        };
        rep.end_fit();
        rep.stage("fit", format!("{} points in {:.1} s after the last frame", out.maps.len(), out.timings.points_s));
        let mut m = assess::replay::material_from(&out, info, q);
        if let (Some(p), Some(prov)) = (&report.partial, m.provenance.as_object_mut()) {
            prov.insert("partial_capture".into(), serde_json::to_value(p)?);
        }
        let m = std::sync::Arc::new(m);
        let dir = root.join("material");
        if *stop.borrow() {
            return Err(Interrupted.into());
        }
        let written = Instant::now();
        tokio::task::block_in_place(|| material::write(&dir, &m, material::WriteMode::Replace))
            .with_context(|| format!("writing {}", dir.display()))?;
        report.time("material_write_s", written.elapsed().as_secs_f64());
        report.time("fit_ingest_s", out.timings.ingest_s);
        report.time("fit_drift_s", out.timings.drift_s);
        report.time("fit_points_s", out.timings.points_s);
        report.time("fit_synthesis_s", out.timings.synthesis_s);
        report.time("fit_synthesis_refit_s", out.timings.refit_s);
        report.time("fit_pool_s", out.timings.pool_s);
        report.time("fit_analytic_s", out.timings.analytic_s);
        report.time("fit_selection_s", out.timings.selection_s);
        if let Some(sel) = &out.selection {
            let s = &sel.summary;
            rep.stage(
                "fit",
                format!(
                    "model choice: {} diffuse, {} {}, {} {}, {} tabulated; storage {:.1} MB instead of {:.1} MB",
                    s.points[0],
                    s.points[1],
                    s.isotropic_model,
                    s.points[2],
                    s.anisotropic_model,
                    s.points[3],
                    s.bytes_chosen as f64 / 1e6,
                    s.bytes_all_tabulated as f64 / 1e6
                ),
            );
        }
        if let Some(st) = &out.synth {
            rep.stage(
                "fit",
                format!(
                    "synthesis completed {} of {} points (+{:.1}% of the hemisphere on average) in {:.1} s",
                    st.completed,
                    st.points,
                    100.0 * st.mean_added_coverage,
                    out.timings.synthesis_s
                ),
            );
        }
        if let Some(d) = &out.drift {
            if d.lights_corrected == 0 {
                rep.warn(format!(
                    "LED drift not corrected: {} of the rig's {} reference patches seen by enough pixels, no reading \
                     usable against the calibration (CALIBRATION.md, \"LED drift\")",
                    d.patches_read, d.patches
                ));
            } else {
                rep.stage(
                    "fit",
                    format!(
                        "LED drift: {} of {} lights corrected from {} reference patches; intensity {:.3}-{:.3} of the \
                         white scan's (mean {:.3})",
                        d.lights_corrected, d.lights, d.patches_read, d.lowest, d.highest, d.mean
                    ),
                );
            }
        }
        if let Some(ps) = &out.pool {
            rep.stage(
                "fit",
                format!(
                    "pooling: {} points share their material's NDF ({} clusters, {} with members turned to its \
                     lobe's axis), {} kept their own, in {:.1} s",
                    ps.pooled, ps.clusters, ps.turned_clusters, ps.kept_own, out.timings.pool_s
                ),
            );
        }
        report.time("fit_total_after_capture_s", t.elapsed().as_secs_f64());
        report.fit = Some(report::FitReport {
            points: out.maps.len(),
            flags: flag_counts(&out.maps.flags),
            samples: out.census,
            sample_store_mb: out.sample_bytes as f64 / 1e6,
            ndf_tables_mb: out.maps.tables.bytes() as f64 / 1e6,
            material_disk_mb: material::io::disk_bytes(&dir) as f64 / 1e6,
            synthesis: out.synth.clone(),
            pooling: out.pool.clone(),
            analytic: out
                .models
                .iter()
                .map(|f| report::AnalyticReport {
                    model: f.model.name().to_string(),
                    seconds: f.seconds,
                    mean_residual: f.residual.iter().flatten().sum::<f32>() / f.residual.len().max(1) as f32,
                    points_without_fit: f.residual.iter().filter(|r| r.is_none()).count(),
                })
                .collect(),
            model_choice: out.selection.as_ref().map(|s| s.summary.clone()),
            drift: out.drift,
        });
        rep.stage("fit", format!("material written to {}", dir.display()));
        let t = Instant::now();
        let files = tokio::task::block_in_place(|| write_renders(root, m, info, rep, &stop_requested(stop)))?;
        if *stop.borrow() {
            return Err(Interrupted.into());
        }
        report.time("renders_s", t.elapsed().as_secs_f64());
        rep.stage(
            "render",
            format!("{} files in {} ({:.1} s)", files.len(), root.join("renders").display(), t.elapsed().as_secs_f64()),
        );
        Ok(dir)
    }
    .await;
    written.map_err(|e| disk_full_advice(e, root))
}

/// Side of the preview renders, in pixels.
pub const PREVIEW_PX: u32 = 160;

/// Write the capture's `renders/` from its material (ground truth beside
/// it for simulated captures).
fn write_renders(
    root: &Path,
    m: std::sync::Arc<Material>,
    info: &CaptureInfo,
    rep: &mut Reporter,
    stop: &dyn Fn() -> bool,
) -> Result<Vec<PathBuf>> {
    let truth = assess::truth::ground_truth(info)?;
    assess::renders::write_previews(&root.join("renders"), m, truth, PREVIEW_PX, rep, stop)
}

pub fn write_report(root: &Path, report: &Report) -> Result<()> {
    let p = root.join("report.json");
    let tmp = root.join(".report.json.tmp");
    std::fs::write(&tmp, serde_json::to_vec_pretty(report)?)
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &p).with_context(|| format!("cannot write {}", p.display()))?;
    Ok(())
}

/// A stored capture as the fit reads it: its description, frames and
/// quality, and how many planned shots it holds.
pub(crate) struct Stored {
    pub info: CaptureInfo,
    pub entries: Vec<store::ManifestEntry>,
    pub q: Quality,
    pub planned: usize,
    pub missing: usize,
}

/// Lock a stored capture (`shared`: beside other readers, as a fit's
/// tiles do; otherwise alone) and read it for a fit. One that misses
/// planned shots is refused unless `partial` (its material is then marked
/// partial).
pub(crate) fn open_stored(
    dir: &Path,
    shared: bool,
    q_override: Option<Quality>,
    partial: bool,
    rep: &mut Reporter,
) -> Result<(store::DirLock, Stored)> {
    let info = store::CaptureDir::read_info(dir)?;
    let lock = if shared { store::DirLock::acquire_shared(dir)? } else { store::DirLock::acquire(dir)? };
    let (entries, torn) = store::CaptureDir::read_manifest(dir)?;
    if torn {
        rep.warn("the manifest's last line is torn (the capture was interrupted); fitting what is complete");
    }
    let planned = store::wanted_shots(&info.plan, &entries);
    let stored: std::collections::HashSet<u32> = entries
        .iter()
        .filter_map(|e| match e.frame {
            store::FrameKind::Shot(shot) => Some(shot.index),
            store::FrameKind::Dark { .. } => None,
        })
        .collect();
    let missing = planned.iter().filter(|s| !stored.contains(&s.index)).count();
    let planned = planned.len();
    let held = planned - missing;
    if missing > 0 {
        let what = format!(
            "{} holds {} of its {planned} planned shots ({:.0}%)",
            dir.display(),
            held,
            100.0 * held as f64 / planned.max(1) as f64
        );
        if !partial {
            return Err(crate::usage(anyhow::anyhow!(
                "{what}: finish it with `capture --resume {}`, or fit what is there with `refl fit --partial`",
                dir.display()
            )));
        }
        rep.warn(format!("{what}; fitting a partial material (--partial)"));
    }
    let q: Quality = match q_override {
        Some(q) => q,
        None => serde_json::from_value(info.settings.clone()).context("capture.json lacks its quality settings")?,
    };
    Ok((lock, Stored { info, entries, q, planned, missing }))
}

/// `refl fit DIR`: refit a stored capture (replaying its frames through the
/// same streaming fitter), writing `material/` and updating `report.json`.
/// A capture missing planned shots is refused unless `partial`; its
/// material is then marked partial in its provenance.
pub async fn refit(
    dir: &Path,
    q_override: Option<Quality>,
    partial: bool,
    rep: &mut Reporter,
    stop: &watch::Receiver<bool>,
) -> Result<PathBuf> {
    let (lock, s) = open_stored(dir, false, q_override, partial, rep)?;
    let inputs = crate::fitjob::fit_inputs(&s.info);
    let job = FitJob::start(inputs, s.q.fit.clone(), s.q.stages(&Overrides::default()));
    let t = Instant::now();
    let n = tokio::task::block_in_place(|| crate::fitjob::replay(dir, &s.entries, &job, &stop_requested(stop)))?;
    rep.stage("fit", format!("{n} stored frames read in {:.1} s", t.elapsed().as_secs_f64()));
    finish_stored(dir, s, job, lock, rep, stop).await
}

/// Write a stored capture's material and report from its fit `job`, and
/// mark the capture complete when it holds every planned shot.
pub(crate) async fn finish_stored(
    dir: &Path,
    s: Stored,
    job: FitJob,
    lock: store::DirLock,
    rep: &mut Reporter,
    stop: &watch::Receiver<bool>,
) -> Result<PathBuf> {
    let Stored { mut info, q, planned, missing, .. } = s;
    let mut report = Report { sample: info.sample.clone(), quality: q.name.clone(), ..Report::default() };
    if missing > 0 {
        info.status = store::CaptureStatus::Interrupted;
        report.partial = Some(report::PartialReport { planned_shots: planned, stored_shots: planned - missing });
    }
    let m = finish_fit(job, &info, &q, dir, rep, &mut report, stop).await?;
    report.peak_memory_mb = report::peak_memory_mb();
    report.material = Some(m.display().to_string());
    write_report(dir, &report).map_err(|e| disk_full_advice(e, dir))?;
    if missing == 0 {
        // Every frame is stored and every output written.
        store::CaptureDir::set_status_locked(dir, &lock, store::CaptureStatus::Complete)?;
    }
    drop(lock);
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A real ENOSPC (writing to /dev/full) while writing the fit's outputs
    /// gets the same advice as during frames: what to free, how to go on,
    /// that nothing is lost.
    #[test]
    fn a_full_disk_during_the_fit_says_how_to_continue() {
        let enospc = std::fs::write("/dev/full", b"maps").expect_err("/dev/full accepts nothing");
        let e = disk_full_advice(anyhow::Error::new(enospc).context("writing /x/material"), Path::new("/x"));
        let msg = format!("{e:#}");
        assert!(msg.contains("full") && msg.contains("capture --resume /x") && msg.contains("refl fit /x"), "{msg}");
        assert!(msg.contains("nothing is lost"), "{msg}");
        let other = disk_full_advice(anyhow::anyhow!("the fitter thread panicked"), Path::new("/x"));
        assert!(!format!("{other:#}").contains("--resume"));
    }
}
