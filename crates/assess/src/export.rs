//! `refl export-samples`: a capture's calibrated samples as NumPy arrays,
//! for people who fit their own models in a notebook.
//!
//! The frames are replayed through the fitter's own ingest (dark frames,
//! flat field, calibrated LED positions and intensities, HDR merge, LED
//! drift), so the samples are exactly those the fitter sees. The file is a
//! `.npz` archive of `.npy` arrays (stored uncompressed, as `numpy.savez`
//! writes them; reflectances do not compress) whose names, shapes and
//! meanings MATERIAL.md lists ("Exported samples").

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use fit::points::SampleNoise;
use fit::{FitContext, Ingest};
use glam::Vec3;
use npyz::WriterBuilder;

use crate::Progress;

/// What was written.
#[derive(Clone, Debug, PartialEq)]
pub struct Exported {
    pub file: PathBuf,
    pub points: usize,
    pub lights: usize,
    /// Samples the fitter uses (non-zero weight).
    pub usable: u64,
    pub bytes: u64,
}

/// Export the samples of capture `dir` into `out` (a new file: an existing
/// one is refused, nothing is replaced). Every `stride`-th point along each
/// axis of the grid. Shots the capture lacks (an unfinished capture) are
/// exported flagged missing, with weight 0.
pub fn export_samples(dir: &Path, out: &Path, stride: u32, progress: &mut dyn Progress) -> Result<Exported> {
    if stride == 0 {
        bail!("--stride must be at least 1");
    }
    if out.exists() {
        bail!("{} exists; nothing was written (remove it or choose another name)", out.display());
    }
    let info = store::CaptureDir::read_info(dir)?;
    let (entries, _torn) = store::CaptureDir::read_manifest(dir)?;
    let ctx = FitContext::new(crate::replay::fit_inputs(&info));
    let g = ctx.inputs.grid;
    let points: Vec<usize> = (0..g.rows)
        .step_by(stride as usize)
        .flat_map(|r| (0..g.cols).step_by(stride as usize).map(move |c| (r * g.cols + c) as usize))
        .collect();
    let lights = ctx.n_lights();
    progress.stage("export", format!("replaying {} frames through the fitter's ingest", entries.len()));
    let mut ingest = Ingest::new(&ctx);
    crate::replay::for_each_frame(dir, &entries, &mut |msg| {
        msg.feed(&mut ingest);
        Ok(())
    })?;
    let (samples, _) = ingest.finish();
    let noise = SampleNoise::new(&ctx);
    let (ctx, samples, noise) = (&ctx, &samples, &noise);

    // Written next to the target and renamed: a failed export leaves no
    // half file under the name asked for.
    let name = out.file_name().ok_or_else(|| anyhow!("{} is not a file name", out.display()))?;
    let tmp = out.with_file_name(format!(".{}.tmp", name.to_string_lossy()));
    let file = std::fs::File::create(&tmp).with_context(|| format!("cannot write {}", tmp.display()))?;
    let mut zip = NpzWriter { zip: zip::ZipWriter::new(std::io::BufWriter::new(file)) };
    let written = (|| -> Result<u64> {
        let n = points.len() as u64;
        let l = lights as u64;
        zip.array("grid", &[2], [g.cols as i64, g.rows as i64])?;
        zip.array("point", &[n], points.iter().map(|&p| p as i64))?;
        zip.array("position_mm", &[n, 3], points.iter().flat_map(|&p| ctx.positions[p].to_array()))?;
        zip.array("view", &[n, 3], points.iter().flat_map(|&p| ctx.view[p].to_array()))?;
        zip.array("light_position_mm", &[l, 3], ctx.lights.iter().flat_map(|q| q.pos.to_array()))?;
        zip.array("luma", &[3], fit::partial::LUMA)?;
        // The fitter's own direction where it has one (`FitContext::sample`);
        // below its grazing limit, the plain direction to the LED.
        zip.array(
            "light",
            &[n, l, 3],
            points.iter().flat_map(|&p| {
                let x = ctx.positions[p];
                ctx.lights.iter().enumerate().flat_map(move |(q, light)| {
                    ctx.sample(p, q).map_or_else(|| (light.pos - x).normalize_or(Vec3::Z), |g| g.i).to_array()
                })
            }),
        )?;
        zip.array("rho", &[n, l, 3], points.iter().flat_map(|&p| (0..lights).flat_map(move |q| samples.get(q, p).0)))?;
        zip.array("flags", &[n, l], points.iter().flat_map(|&p| (0..lights).map(move |q| samples.get(q, p).1)))?;
        let mut usable = 0u64;
        let weights = points
            .iter()
            .flat_map(|&p| {
                let footprint = noise.footprint(ctx, p);
                (0..lights).map(move |q| {
                    let (rho, fl) = samples.get(q, p);
                    let in_view = ctx.pixels[p].is_some();
                    match noise.usable(ctx, p, q, rho, fl, &footprint).filter(|_| in_view) {
                        Some((_, var)) => 1.0 / var.lum,
                        None => 0.0,
                    }
                })
            })
            .inspect(|w| usable += u64::from(*w > 0.0));
        zip.array("weight", &[n, l], weights)?;
        let channel_weights = points.iter().flat_map(|&p| {
            let footprint = noise.footprint(ctx, p);
            (0..lights).flat_map(move |q| {
                let (rho, fl) = samples.get(q, p);
                let in_view = ctx.pixels[p].is_some();
                match noise.usable(ctx, p, q, rho, fl, &footprint).filter(|_| in_view) {
                    Some((_, var)) => var.channel.map(|v| 1.0 / v),
                    None => [0.0; 3],
                }
            })
        });
        zip.array("channel_weight", &[n, l, 3], channel_weights)?;
        Ok(usable)
    })();
    let finished = written.and_then(|usable| {
        let mut w = zip.zip.finish().context("finishing the archive")?;
        w.flush()?;
        w.get_ref().sync_all()?;
        Ok(usable)
    });
    let usable = match finished {
        Ok(u) => u,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e.context(format!("writing {}", out.display())));
        }
    };
    // A name taken meanwhile is not replaced.
    if out.exists() {
        let _ = std::fs::remove_file(&tmp);
        bail!("{} appeared while exporting; nothing was replaced", out.display());
    }
    std::fs::rename(&tmp, out).with_context(|| format!("cannot write {}", out.display()))?;
    let bytes = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0);
    Ok(Exported { file: out.to_path_buf(), points: points.len(), lights, usable, bytes })
}

/// `.npy` arrays into a zip archive, one entry each.
struct NpzWriter<W: Write + std::io::Seek> {
    zip: zip::ZipWriter<W>,
}

impl<W: Write + std::io::Seek> NpzWriter<W> {
    fn array<T: npyz::Serialize + npyz::AutoSerialize>(
        &mut self,
        name: &str,
        shape: &[u64],
        values: impl IntoIterator<Item = T>,
    ) -> Result<()> {
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored)
            .large_file(true);
        self.zip.start_file(format!("{name}.npy"), options).with_context(|| format!("starting {name}.npy"))?;
        let mut w = npyz::WriteOptions::new().default_dtype().shape(shape).writer(&mut self.zip).begin_nd()?;
        let mut count = 0u64;
        for v in values {
            w.push(&v)?;
            count += 1;
        }
        w.finish()?;
        let want: u64 = shape.iter().product();
        if count != want {
            bail!("{name}: {count} values for shape {shape:?}");
        }
        Ok(())
    }
}
