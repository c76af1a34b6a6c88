//! `refl bench`: the figures the issues ask for, printed by commands anyone
//! can run on inputs the repository makes.
//!
//! - `fit`: the fitter's stages in points per second and the process's
//!   peak memory, on a synthetic capture written straight into the sample
//!   store (a simulated material evaluated at every (light, point) pair
//!   with 1% noise): the default preset's size, or the talk's 800 x 800
//!   points x 2,560 lights with `--points 800 --steps 64`; the per-point
//!   fit and synthesis, or with `--preset Q` every stage of a preset.
//! - `synthesis`: the three search modes on the same partial tables
//!   (time, points per second, NDF error against ground truth).
//! - `camera`, `protocol`, `synthesis-scale`: the simulated camera's frame
//!   rate, the serial link's round trips, the synthesis at the talk's scale.
//!
//! `realtime`, which runs the whole capture job, is the application's
//! (`cli::bench`).

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Result, anyhow};
use brdf::Brdf;
use brdf::ndf::{MaskingOperator, NdfTable, TableSet};
use fit::samples::{SampleStore, flag};
use fit::synth::{SearchMode, SynthSettings, synthesize};
use fit::{FitContext, FitInputs, FitSettings};
use glam::Vec2;
use half::f16;
use material::SvBrdf;
use rayon::prelude::*;
use setup::{Calibration, CapturePlan, PointGrid, RigGeometry};

use crate::report::{peak_memory_mb, resident_memory_mb};

/// A synthetic capture in memory: its context and filled sample store.
pub struct Synthetic {
    pub ctx: FitContext,
    pub store: SampleStore,
    pub material: Arc<dyn SvBrdf>,
}

impl std::fmt::Debug for Synthetic {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Synthetic").field("points", &self.ctx.n_points()).field("lights", &self.ctx.n_lights()).finish()
    }
}

/// The synthetic rig's radiometry: LED intensity (so that a white point
/// 4 cm under an LED reads about 2,000 DN in 20 ms), read noise and
/// electrons per DN of a typical 12-bit machine-vision sensor.
const LED_SCALE: f32 = 5e8;
const READ_NOISE_DN: f32 = 2.0;
const E_PER_DN: f32 = 4.0;
const EXPOSURE_S: f32 = 0.02;

/// Cheap deterministic noise in [-1, 1] (a hash of the sample index).
fn unit_noise(k: u64) -> f32 {
    let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
    x ^= x >> 31;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 29;
    (x >> 40) as f32 / (1u64 << 23) as f32 - 1.0
}

/// The sample store of `material` on a `side` x `side` grid lit from
/// `steps` gantry positions x every `led_stride`-th LED of the default rig.
/// With `noise` false every sample is exact (the fitter still weights
/// samples by the noise model's variance).
pub fn synthetic(material: Arc<dyn SvBrdf>, side: u32, steps: u32, led_stride: u32, noise: bool) -> Result<Synthetic> {
    synthetic_through(material, side, steps, led_stride, noise, None)
}

/// The fit context of [`synthetic`]'s rig and plan, without its samples.
pub fn synthetic_context(side: u32, steps: u32, led_stride: u32) -> Result<FitContext> {
    let mut g = RigGeometry::default();
    // A camera fine enough that every point has its own pixel.
    g.camera.width = (side * 5 / 4).max(64);
    g.camera.height = g.camera.width;
    let plan = CapturePlan {
        steps,
        first_mm: g.gantry.travel_min_mm,
        last_mm: g.gantry.travel_max_mm,
        leds: (0..g.bar.n_leds).step_by(led_stride.max(1) as usize).collect(),
        exposures_us: vec![(EXPOSURE_S * 1e6) as u32],
        gain: 1.0,
        dark_frames: 0,
        bracket: setup::Bracket::Every,
    };
    plan.validate(&g)?;
    let inputs = FitInputs {
        geometry: g.clone(),
        plan,
        calibration: Calibration {
            led_scale: vec![LED_SCALE; g.bar.n_leds as usize],
            read_noise_dn: [READ_NOISE_DN; 3],
            ..Calibration::nominal(g.bar.n_leds, 1.0, 0.0)
        },
        grid: PointGrid { cols: side, rows: side },
        e_per_dn: E_PER_DN,
        bit_depth: 12,
        sensor_layout: None,
    };
    Ok(FitContext::new(inputs))
}

/// [`synthetic`], with each point's samples, when `footprint` names a
/// camera and its sensor's layout, those of the mean BRDF over the
/// footprint through which that camera would read the point
/// (`crate::footprint::mean_at`): the one part of the camera's effect that
/// is not noise (`refl bench budget`'s footprint row). The ground truth the
/// budget scores against stays the point's centre.
pub fn synthetic_through(
    material: Arc<dyn SvBrdf>,
    side: u32,
    steps: u32,
    led_stride: u32,
    noise: bool,
    footprint: Option<(setup::CameraModel, frame::Layout)>,
) -> Result<Synthetic> {
    let ctx = synthetic_context(side, steps, led_stride)?;
    let sample_area = ctx.inputs.geometry.sample;
    let (n, nl) = (ctx.n_points(), ctx.n_lights());
    let mut store = SampleStore::new(n, nl);
    let points: Vec<_> = ctx
        .positions
        .iter()
        .map(|x| {
            let pos = Vec2::new(x.x, x.y);
            footprint
                .and_then(|(cam, layout)| {
                    crate::footprint::mean_at(&cam, Some(layout), &sample_area, material.as_ref(), pos)
                })
                .unwrap_or_else(|| material.at(pos))
        })
        .collect();
    for q in 0..nl {
        store.edit_row(q, |rho, fl| {
            rho.par_iter_mut().zip(fl.par_iter_mut()).enumerate().for_each(|(p, (r, f))| {
                if ctx.pixels[p].is_none() {
                    *f = flag::OUT_OF_VIEW;
                    return;
                }
                let Some(s) = ctx.sample(p, q) else {
                    *f = flag::DIM;
                    return;
                };
                if s.occluded {
                    *f = flag::OCCLUDED;
                    return;
                }
                let v = points[p].eval(s.i, ctx.view[p]);
                let out = [v.x, v.y, v.z];
                // The fitter's noise model (`fit::points::gather`): rho = DN k.
                let k = s.to_rho / (EXPOSURE_S * 1.0);
                let h = (q * n + p) as u64 * 3;
                *r = std::array::from_fn(|c| {
                    let sd = (k * k * READ_NOISE_DN * READ_NOISE_DN + k * out[c].max(0.0) / E_PER_DN).sqrt();
                    // Uniform on [-sqrt 3, sqrt 3]: unit variance.
                    let e = if noise { sd * 1.732 * unit_noise(h + c as u64) } else { 0.0 };
                    f16::from_f32(out[c] + e)
                });
                *f = 0;
            });
        });
    }
    Ok(Synthetic { ctx, store, material })
}

fn mem() -> String {
    peak_memory_mb().map_or("?".into(), |m| format!("{:.0} MB", m))
}

/// What `refl bench fit` runs after the per-point fit.
#[derive(Clone, Debug)]
pub enum BenchStages {
    /// The per-point fit alone.
    PointsOnly,
    /// The per-point fit, then synthesis (its clusters scaled to the grid,
    /// a hundred points each, 8 to 1,000) and the refit of completed points.
    Synthesis,
    /// Every stage of a quality preset, with its fit settings: what
    /// `capture --quality Q --grid N` fits (synthesis, analytic fits,
    /// pooling and the model choice's refit and scores).
    Preset(Box<config::Quality>),
}

/// `refl bench fit`.
pub fn fit(sample: &str, side: u32, steps: u32, led_stride: u32, ndf_theta: u32, run: &BenchStages) -> Result<()> {
    let material = crate::truth::sim_material(sample, None)?;
    let grid = brdf::ndf::NdfGrid { n_theta: ndf_theta, n_phi: 3 * ndf_theta };
    let (settings, stages, what) = match run {
        BenchStages::Preset(q) => (
            FitSettings { grid, ..q.fit.clone() },
            q.stages(&config::Overrides::default()),
            format!("every stage of the {} preset", q.name),
        ),
        _ => (FitSettings { grid, ..FitSettings::default() }, fit::Stages::default(), "default fit settings".into()),
    };
    println!(
        "fit benchmark: '{sample}', {side} x {side} points, {steps} steps x every {led_stride} LED, NDF {ndf_theta} x {} cells, {what}, {} threads",
        3 * ndf_theta,
        rayon::current_num_threads()
    );
    let t = Instant::now();
    let s = synthetic(material, side, steps, led_stride, true)?;
    let n = s.ctx.n_points();
    println!(
        "  synthetic samples: {} lights x {n} points = {:.2} G samples, {:.2} GB store, {:.1} s (not a fitter stage); peak memory {}",
        s.ctx.n_lights(),
        (n * s.ctx.n_lights()) as f64 / 1e9,
        s.store.bytes() as f64 / 1e9,
        t.elapsed().as_secs_f64(),
        mem()
    );
    let stages = match run {
        BenchStages::Synthesis => {
            let clusters = (n as u32 / 100).clamp(8, 1000);
            fit::Stages { synth: Some(SynthSettings { clusters, ..SynthSettings::default() }), ..stages }
        }
        _ => stages,
    };
    let rss = RssMonitor::start();
    let r = fit::pipeline::run_stages(&s.ctx, s.store, settings, &stages, &|| false)?;
    let (rss, heap) = rss.finish();
    let tm = &r.timings;
    // The stages run one after another in this order from the monitor's
    // start: each one's peak is the largest resident size sampled within
    // its span, and the largest allocation.
    let spans = [tm.points_s, tm.synthesis_s, tm.analytic_s, tm.pool_s, tm.selection_s];
    let (peaks, allocated) = (stage_peaks(&rss, &spans), stage_peaks(&heap, &spans));
    let peak = |k: usize| {
        let mb = |m: Option<f64>| m.map_or("?".into(), |m| format!("{m:.0} MB"));
        if heap.is_empty() {
            mb(peaks[k])
        } else {
            format!("{} (allocated at most {})", mb(peaks[k]), mb(allocated[k]))
        }
    };
    let dt = tm.points_s;
    let no_spec = r.maps.flags.iter().filter(|&&f| f & fit::point_flag::NO_SPECULAR != 0).count();
    println!(
        "  per-point fit (gather, diffuse, splat, push-pull, masking, Fresnel): {:.1} s, {:.0} points/s; {no_spec} without specular; resident at most {}",
        dt,
        n as f64 / dt,
        peak(0)
    );
    if let (Some(st), Some(ss)) = (&r.synth, &stages.synth) {
        let dt = tm.synthesis_s;
        println!(
            "  synthesis ({:?}, {} clusters) and the refit with the completed NDFs: {:.1} s (refit {:.1} s), {:.0} points/s; completed {} of {}; resident at most {}",
            ss.mode,
            ss.clusters,
            dt,
            tm.refit_s,
            n as f64 / dt,
            st.completed,
            st.points,
            peak(1)
        );
    }
    if !r.models.is_empty() {
        println!("  analytic fits ({} models): {:.1} s; resident at most {}", r.models.len(), tm.analytic_s, peak(2));
    }
    if let Some(p) = &r.pool {
        println!(
            "  pooling: {:.1} s, {:.0} points/s; {} clusters, {} points pooled, {} kept their own table; resident at most {}",
            tm.pool_s,
            n as f64 / tm.pool_s,
            p.clusters,
            p.pooled,
            p.kept_own,
            peak(3)
        );
    }
    if let Some(sel) = &r.selection {
        println!(
            "  model choice (refit without the held-out steps, scores): {:.1} s; points per class (diffuse, isotropic, anisotropic, tabulated) {:?}; resident at most {}",
            tm.selection_s,
            sel.summary.points,
            peak(4)
        );
    }
    if matches!(run, BenchStages::Preset(_)) {
        println!("  every stage: {:.1} s (the material's writing not included)", spans.iter().sum::<f64>());
    }
    println!("  peak memory {}", mem());
    Ok(())
}

/// How often [`RssMonitor`] reads the resident size.
const RSS_PERIOD: std::time::Duration = std::time::Duration::from_millis(20);

/// Readings of the resident size per reading of the heap's allocation
/// ([`heap_allocated_mb`], which walks the allocator's free lists under its
/// locks: every 100 ms, not every 20).
const HEAP_EVERY: usize = 5;

/// A thread reading the process's resident size every [`RSS_PERIOD`] from
/// its start, and the heap's allocation every [`HEAP_EVERY`]-th time, so that a
/// run of stages can be given each stage's peak of both. The resident size
/// is what the machine must have; but memory a stage frees stays resident
/// for the allocator to reuse, so a later stage that needs less shows the
/// earlier one's peak, which the allocation does not.
struct RssMonitor {
    stop: Arc<std::sync::atomic::AtomicBool>,
    thread: std::thread::JoinHandle<(Readings, Readings)>,
}

/// (seconds from the start, MB) readings.
type Readings = Vec<(f64, f64)>;

impl RssMonitor {
    fn start() -> Self {
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let halt = stop.clone();
        let t = Instant::now();
        let thread = std::thread::spawn(move || {
            let (mut seen, mut heap) = (Vec::new(), Vec::new());
            for k in 0.. {
                let done = halt.load(std::sync::atomic::Ordering::Relaxed);
                if let Some(mb) = resident_memory_mb() {
                    seen.push((t.elapsed().as_secs_f64(), mb));
                }
                if (k % HEAP_EVERY == 0 || done)
                    && let Some(mb) = heap_allocated_mb()
                {
                    heap.push((t.elapsed().as_secs_f64(), mb));
                }
                if done {
                    break;
                }
                std::thread::sleep(RSS_PERIOD);
            }
            (seen, heap)
        });
        Self { stop, thread }
    }

    /// The readings of the resident size and of the heap's allocation (none where it cannot be read), the last ones
    /// taken after this call.
    fn finish(self) -> (Readings, Readings) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        self.thread.join().unwrap_or_default()
    }
}

/// The bytes the allocator has handed out and not had back, MB: glibc's
/// `mallinfo2` (glibc 2.33 and later; Debian 12, the rig PC's and CI's
/// system, has 2.36), the chunks in use in every arena and the blocks
/// mapped on their own.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn heap_allocated_mb() -> Option<f64> {
    // SAFETY: `mallinfo2` takes no arguments and returns a plain struct; it
    // only reads the allocator's statistics, under the allocator's locks.
    let m = unsafe { libc::mallinfo2() };
    Some((m.uordblks + m.hblkhd) as f64 / 1e6)
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn heap_allocated_mb() -> Option<f64> {
    None
}

/// Per span of `spans` (seconds, back to back from 0), the largest reading
/// of `seen` within it; the last span runs to the last reading. `None` for
/// a span no reading fell in.
fn stage_peaks(seen: &[(f64, f64)], spans: &[f64]) -> Vec<Option<f64>> {
    let mut start = 0.0;
    let last = spans.iter().rposition(|&d| d > 0.0);
    spans
        .iter()
        .enumerate()
        .map(|(k, &d)| {
            let end = if Some(k) == last { f64::INFINITY } else { start + d };
            let peak = seen.iter().filter(|&&(t, _)| t >= start && t < end).map(|&(_, m)| m).reduce(f64::max);
            start += d;
            peak.filter(|_| d > 0.0)
        })
        .collect()
}

/// Pooled relative L2 error of `tables` against the truth over the whole
/// hemisphere, over points with specular.
pub fn ndf_error(s: &Synthetic, flags: &[u32], tables: &TableSet) -> f64 {
    let grid = tables.grid();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for p in 0..tables.len() {
        if flags[p] & fit::point_flag::NO_SPECULAR != 0 {
            continue;
        }
        let x = s.ctx.positions[p];
        let Some(ndf) = s.material.at(Vec2::new(x.x, x.y)).ndf().cloned() else { continue };
        let mut t = NdfTable::from_ndf(grid, &ndf);
        if t.normalize() <= 0.0 {
            continue;
        }
        if let Some((n, d)) = tables.get(p).l2_sums(&t, |_| true) {
            num += n;
            den += d;
        }
    }
    (num / den.max(1e-30)).sqrt()
}

/// `refl bench synthesis`.
pub fn synthesis(
    sample: &str,
    side: u32,
    steps: u32,
    modes: &[SearchMode],
    clusters: Option<u32>,
    search: (Option<u32>, Option<u32>),
) -> Result<()> {
    let base = SynthSettings::default();
    let (rotations, neighbours) = (search.0.unwrap_or(base.rotations), search.1.unwrap_or(base.neighbours));
    let material = crate::truth::sim_material(sample, None)?;
    let s = synthetic(material, side, steps, 1, true)?;
    let n = s.ctx.n_points();
    let settings = FitSettings::default();
    let op = MaskingOperator::new(settings.grid);
    let maps = fit::points::fit_points(&s.ctx, &s.store, &settings, &op);
    let eligible: Vec<bool> = maps.flags.iter().map(|f| f & fit::point_flag::NO_SPECULAR == 0).collect();
    let clusters = clusters.unwrap_or((n as u32 / 100).clamp(8, 1000));
    println!(
        "synthesis benchmark: '{sample}', N = {n} points ({} with specular), {clusters} clusters, {rotations} rotation angles, {neighbours} neighbours, {} threads",
        eligible.iter().filter(|&&e| e).count(),
        rayon::current_num_threads()
    );
    println!("  partial tables: NDF error over the hemisphere {:.4}", ndf_error(&s, &maps.flags, &maps.tables));
    for &mode in modes {
        let t = Instant::now();
        let out = synthesize(
            &maps.tables,
            &eligible,
            &SynthSettings { mode, clusters, rotations, neighbours, ..base.clone() },
        );
        let dt = t.elapsed().as_secs_f64();
        println!(
            "  {mode:?}: {:.2} s ({:.0} points/s), {} candidates scored, {} pruned, NDF error {:.4}; peak memory {}",
            dt,
            n as f64 / dt,
            out.stats.candidates_scored,
            out.stats.pruned,
            ndf_error(&s, &maps.flags, &out.tables),
            mem()
        );
    }
    Ok(())
}

/// Parse a comma-separated list of search modes.
pub fn parse_modes(s: &str) -> Result<Vec<SearchMode>> {
    s.split(',')
        .map(|m| match m.trim() {
            "brute" | "brute-force" => Ok(SearchMode::BruteForce),
            "clustered" => Ok(SearchMode::Clustered),
            "accelerated" => Ok(SearchMode::Accelerated),
            o => Err(anyhow!("unknown search mode '{o}': brute, clustered, accelerated")),
        })
        .collect()
}

/// `refl bench camera`: simulated frames per second (render, noise and
/// quantisation of one frame) at `px` x `px`, one LED lit.
pub fn camera(sample: &str, px: u32, frames: u32) -> Result<f64> {
    use sim::camera::{CameraTiming, LedTruth, SensorModel, SimCamera, SimCameraConfig};
    let material = crate::truth::sim_material(sample, None)?;
    let mut g = RigGeometry::default();
    g.camera.width = px;
    g.camera.height = px;
    let cfg = SimCameraConfig {
        truth: sim::RigTruth::ideal(&g),
        sensor: SensorModel::default(),
        leds: LedTruth::realistic(g.bar.n_leds, 1),
        timing: CameraTiming::Fast { time_scale: 0.0 },
        seed: 1,
        faults: sim::FaultSpec::default(),
        rest_um: 0.0,
    };
    let mut cam = SimCamera::new(cfg, material, sim::World::new());
    let _ = cam.render_direct(0, Some(0));
    let t = Instant::now();
    for k in 0..frames {
        let x = -100_000 + (k as i32 * 7919) % 200_000;
        let _ = cam.render_direct(x, Some((k % g.bar.n_leds as u32) as u8));
    }
    let fps = frames as f64 / t.elapsed().as_secs_f64();
    println!("simulated camera, '{sample}', {px} x {px}: {fps:.1} frames/s ({frames} frames)");
    Ok(fps)
}

/// `refl bench protocol`: the serial protocol over a real pseudo-terminal
/// to the emulated MCU: status round trips per second, and the time the
/// driver takes per LED firing (`SetLed` sent to its `Ack` received).
pub async fn protocol(n: u32) -> Result<()> {
    use rig::mcu::{PortLocator, Rig, SerialConnector};
    let g = RigGeometry::default();
    let cfg = sim::McuConfig::for_geometry(&g, 0.001);
    let dir = std::env::temp_dir().join(format!("refl-bench-protocol-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let link = dir.join("mcu");
    let mcu = sim::SimMcu::spawn_pty(cfg, sim::FaultSpec::default(), sim::World::new(), Some(link.clone())).await?;
    let settings = rig::mcu::RigSettings::for_geometry(&g, 0.001, 200);
    let mut rig =
        Rig::open(SerialConnector { locator: PortLocator::Path { path: link }, baud: 1_000_000 }, settings).await?;
    rig.home().await?;
    let t = Instant::now();
    for _ in 0..n {
        rig.status().await?;
    }
    let dt = t.elapsed().as_secs_f64();
    println!(
        "status round trips over a PTY: {:.0} per second ({:.1} us each, {n} round trips)",
        n as f64 / dt,
        dt / n as f64 * 1e6
    );
    let t = Instant::now();
    for k in 0..n {
        rig.led_on((k % 40) as u8).await?;
    }
    let dt = t.elapsed().as_secs_f64();
    rig.all_off().await?;
    println!("LED firings (SetLed to Ack): {:.1} us each ({n} firings)", dt / n as f64 * 1e6);
    let s = rig.link_stats();
    println!("link: {} commands, {} retransmits, mean round trip {:?}", s.commands, s.retransmits, s.mean_rtt());
    rig.shutdown().await;
    mcu.stop().await?;
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// `refl bench synthesis-scale`: the time of the accelerated synthesis at
/// the talk's scale, on partial tables made directly (not fitted): each of
/// `points` points gets `sample`'s NDF at a position on a square grid,
/// observed inside a cone of `cone_deg` about an axis 20 degrees off the
/// normal (the kind of region a single view observes). Only the time and memory are meaningful here; the
/// accuracy figures come from `refl bench synthesis`.
pub fn synthesis_scale(sample: &str, points: usize, clusters: u32, rotations: u32, cone_deg: f32) -> Result<()> {
    let material = crate::truth::sim_material(sample, None)?;
    let grid = brdf::ndf::NdfGrid::DEFAULT;
    let side = (points as f64).sqrt().ceil() as usize;
    let cone = cone_deg.to_radians();
    // One view's observed region is off the normal (toward the camera's
    // mirror side), so rotated candidates add to it.
    let axis = glam::Vec3::new(20f32.to_radians().sin(), 0.0, 20f32.to_radians().cos());
    println!(
        "synthesis at scale: '{sample}', N = {points} points, {clusters} clusters, {rotations} rotation angles, NDF {} x {} cells, {} threads",
        grid.n_theta,
        grid.n_phi,
        rayon::current_num_threads()
    );
    let t = Instant::now();
    let tables: Vec<NdfTable> = (0..points)
        .into_par_iter()
        .map(|p| {
            let (c, r) = (p % side, p / side);
            let x = Vec2::new((c as f32 + 0.5) / side as f32 - 0.5, 0.5 - (r as f32 + 0.5) / side as f32) * 100.0;
            let mut t = match material.at(x).ndf() {
                Some(n) => NdfTable::from_fn(grid, 1, |h| n.d(h)),
                None => NdfTable::zeros(grid),
            };
            for k in 0..grid.len() {
                let h = grid.direction(k / grid.n_phi as usize, k % grid.n_phi as usize);
                let seen = h.dot(axis) >= cone.cos();
                t.coverage_mut().set(k, seen);
                if !seen {
                    t.values_mut()[k] = 0.0;
                }
            }
            t.normalize();
            t
        })
        .collect();
    let mut set = TableSet::new(grid, points);
    for (p, t) in tables.iter().enumerate() {
        set.set(p, t);
    }
    drop(tables);
    println!("  partial tables made in {:.1} s; peak memory {}", t.elapsed().as_secs_f64(), mem());
    let eligible = vec![true; points];
    let t = Instant::now();
    let out = synthesize(&set, &eligible, &SynthSettings { clusters, rotations, ..SynthSettings::default() });
    let dt = t.elapsed().as_secs_f64();
    println!(
        "  accelerated synthesis: {dt:.1} s ({:.0} points/s; clustering {:.1} s, search {:.1} s, fill {:.1} s); completed {} of {}; {} candidates scored, {} pruned; peak memory {}",
        points as f64 / dt,
        out.stats.cluster_seconds,
        out.stats.search_seconds,
        out.stats.fill_seconds,
        out.stats.completed,
        out.stats.points,
        out.stats.candidates_scored,
        out.stats.pruned,
        mem()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_stage_is_given_the_peak_read_within_its_span() {
        let seen = [(0.0, 10.0), (0.5, 30.0), (1.0, 20.0), (1.5, 25.0), (2.5, 40.0), (3.2, 15.0)];
        // Points 0-1 s, synthesis 1-2 s, no analytic fits, pooling to the end.
        let peaks = stage_peaks(&seen, &[1.0, 1.0, 0.0, 0.5]);
        assert_eq!(peaks, vec![Some(30.0), Some(25.0), None, Some(40.0)]);
        // A span with no reading in it has no peak.
        assert_eq!(stage_peaks(&seen, &[0.2, 0.2, 5.0]), vec![Some(10.0), None, Some(40.0)]);
    }

    fn through(sample: &str) -> (Synthetic, Synthetic) {
        let material = crate::truth::sim_material(sample, None).unwrap();
        let mut cam = RigGeometry::default().camera;
        (cam.width, cam.height) = (128, 128);
        let layout = frame::Layout::Bayer { pattern: frame::BayerPattern::Rggb };
        (
            synthetic(material.clone(), 12, 8, 4, false).unwrap(),
            synthetic_through(material, 12, 8, 4, false, Some((cam, layout))).unwrap(),
        )
    }

    /// The largest relative difference between two synthetic captures'
    /// usable samples.
    fn largest_difference(a: &Synthetic, b: &Synthetic) -> f32 {
        let mut worst = 0.0f32;
        for q in 0..a.ctx.n_lights() {
            for p in 0..a.ctx.n_points() {
                let ((ra, fa), (rb, fb)) = (a.store.get(q, p), b.store.get(q, p));
                assert_eq!(fa, fb, "the footprint changes no flag");
                for c in 0..3 {
                    let scale = ra[c].abs().max(rb[c].abs()).max(1e-3);
                    worst = worst.max((ra[c] - rb[c]).abs() / scale);
                }
            }
        }
        worst
    }

    /// Read through the camera's pixels, a uniform surface gives the same
    /// samples (to f16's precision, 1e-3, and the f32 sum of the taps'
    /// shares); satin, whose weave varies within a footprint, does not.
    #[test]
    fn the_camera_footprint_changes_only_what_varies_within_it() {
        let (a, b) = through("ward");
        let d = largest_difference(&a, &b);
        assert!(d < 2e-3, "ward: {d}");
        let (a, b) = through("satin");
        let d = largest_difference(&a, &b);
        assert!(d > 0.05, "satin: {d}");
    }
}
