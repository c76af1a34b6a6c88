//! `capture`: the lab operator's acquisition command.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use cli::capture::{self, CaptureRequest};
use cli::progress::Reporter;
use config::Overrides;
use config::RigFile;

/// Scan a flat material sample and fit its spatially varying, anisotropic
/// reflectance. With no rig configured it runs the simulated rig.
#[derive(Debug, Parser)]
#[command(
    name = "capture",
    version,
    after_help = "Examples:\n  capture --sample satin --out runs/satin\n  capture --resume runs/satin\n  capture --calibrate dark && capture --calibrate white"
)]
struct Args {
    /// Sample name (on the simulated rig: a built-in material, see --list-samples).
    #[arg(long)]
    sample: Option<String>,
    /// Capture directory to create.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Continue an interrupted capture in DIR (verifies every stored frame).
    #[arg(long, value_name = "DIR", conflicts_with_all = ["sample", "out", "calibrate"])]
    resume: Option<PathBuf>,
    /// Speed/accuracy preset: fast, balanced or best.
    #[arg(long, default_value = "balanced")]
    quality: String,
    /// Rig file (default: /etc/reflectometer/rig.toml if present, else the simulated rig).
    #[arg(long, value_name = "FILE")]
    rig: Option<PathBuf>,
    /// Simulated rig: use a stored material as the ground truth.
    #[arg(long, value_name = "DIR")]
    sim_material: Option<PathBuf>,
    /// Simulated rig: the physical rig behind the rig file, `ideal` or
    /// `perturbed:SEED` (default: the rig file's `[sim] rig`).
    #[arg(long, value_name = "RIG")]
    sim_rig: Option<String>,
    /// Simulated rig: inject faults, e.g. corrupt=0.01,drop=0.005,reboot-at=500.
    #[arg(long, value_name = "SPEC", default_value = "")]
    sim_faults: String,
    /// Record a calibration instead of a sample: `dark` (lens capped), `white` (white reference),
    /// `geometry` (the checkerboard target, see CALIBRATION.md) or `all` (geometry, dark, white).
    #[arg(long, value_parser = ["dark", "white", "geometry", "all"])]
    calibrate: Option<String>,
    /// Where calibrations are kept (default: the data directory).
    #[arg(long, value_name = "DIR")]
    calib_dir: Option<PathBuf>,
    /// Gantry steps (overrides the preset).
    #[arg(long)]
    steps: Option<u32>,
    /// Use every N-th LED (overrides the preset).
    #[arg(long)]
    led_stride: Option<u8>,
    /// HDR brackets per LED, 8x apart (overrides the preset).
    #[arg(long)]
    hdr: Option<u32>,
    /// Which shorter exposures of the bracket to take: `clipped` (only for a light whose longer
    /// exposure clipped on the sample; the presets' choice) or `every` (overrides the preset).
    #[arg(long, value_name = "WHICH")]
    bracket: Option<setup::Bracket>,
    /// Sample points per side of the fitted material (overrides the preset).
    #[arg(long)]
    grid: Option<u32>,
    /// Simulated camera pixels per side (overrides the preset).
    #[arg(long)]
    camera_px: Option<u32>,
    /// NDF table rings (the table is RINGS x 3*RINGS cells; overrides the preset).
    #[arg(long)]
    ndf_theta: Option<u32>,
    /// k-means clusters for microfacet synthesis (overrides the preset).
    #[arg(long)]
    clusters: Option<u32>,
    /// Skip microfacet synthesis (keep the partial NDFs).
    #[arg(long)]
    no_synthesis: bool,
    /// Skip the analytic fits and the per-point model choice.
    #[arg(long)]
    no_analytic: bool,
    /// Fit every point's NDF from its own samples alone (no pooling of a
    /// material's points).
    #[arg(long)]
    no_pooling: bool,
    /// Capture only; do not fit.
    #[arg(long)]
    no_fit: bool,
    /// Emit machine-readable progress events (JSON lines on stdout).
    #[arg(long)]
    json: bool,
    /// List the simulated rig's built-in samples and exit.
    #[arg(long)]
    list_samples: bool,
    /// List this machine's V4L2 cameras (name, path, formats, sizes) and exit.
    #[arg(long)]
    list_cameras: bool,
    /// Run in this process even when a capture daemon (`refl daemon`) is running.
    #[arg(long)]
    no_daemon: bool,
    /// Log lines as text or as JSON objects (for the journal).
    #[arg(long, value_enum, default_value = "text")]
    log_format: cli::LogFormat,
    /// Stop after this many shots, keeping everything (for demonstrations of --resume).
    #[arg(long, hide = true)]
    stop_after: Option<u64>,
}

fn main() -> ExitCode {
    // Before anything the build's instruction set could be used in
    // (`cli::cpu`).
    cli::cpu::check();
    run()
}

#[inline(never)]
fn run() -> ExitCode {
    let args = Args::parse();
    cli::init_logging(args.log_format);
    if args.list_samples {
        cli::quiet_on_closed_stdout();
        for (n, d) in sim::materials::BUILTIN {
            println!("{n:14} {d}");
        }
        return ExitCode::SUCCESS;
    }
    if args.list_cameras {
        return list_cameras(args.json);
    }
    let mut rep = Reporter::auto(args.json);
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::from(cli::exit::FAILED as u8);
        }
    };
    let result = rt.block_on(async {
        let mut stop = cli::stop_on_signals()?;
        if let Some(which) = &args.calibrate {
            let (mut rf, _) = RigFile::load(args.rig.as_deref())?;
            if let Some(r) = &args.sim_rig {
                rf.sim.rig = r.parse().map_err(|e| cli::usage(anyhow::anyhow!("--sim-rig: {e}")))?;
            }
            let q = config::preset(&args.quality)
                .ok_or_else(|| cli::usage(anyhow::anyhow!("unknown quality '{}'", args.quality)))?;
            let g = capture::geometry_for(&rf, &q);
            let store = cli::paths::calibrations(args.calib_dir.as_deref(), &rf.calibration_key())?;
            let c = tokio::select! {
                c = capture::calibrate(&rf, &g, &store, &mut rep, which.parse()?) => c?,
                _ = stop.wait_for(|s| *s) => return Err(cli::Interrupted.into()),
            };
            rep.emit(cli::progress::Event::Done { summary: serde_json::json!({ "calibration": c.id }) });
            return anyhow::Ok(0);
        }
        let req = CaptureRequest {
            sample: args.sample.clone(),
            out: args.out.clone(),
            resume: args.resume.clone(),
            quality: Some(args.quality.clone()),
            overrides: Overrides {
                steps: args.steps,
                led_stride: args.led_stride,
                hdr: args.hdr,
                bracket: args.bracket,
                grid: args.grid,
                camera_px: args.camera_px,
                ndf_theta: args.ndf_theta,
                clusters: args.clusters,
                no_synthesis: args.no_synthesis,
                no_analytic: args.no_analytic,
                no_pooling: args.no_pooling,
            },
            rig_file: args.rig.clone(),
            sim_material: args.sim_material.clone(),
            sim_faults: args.sim_faults.clone(),
            sim_rig: args.sim_rig.clone(),
            calib_dir: args.calib_dir.clone(),
            no_fit: args.no_fit,
            stop_after: args.stop_after,
        };
        if !args.no_daemon {
            if let Some((socket, stream)) = cli::daemon::connect().await? {
                rep.stage("capture", format!("handing the job to the daemon on {}", socket.display()));
                return cli::daemon::capture_via(&socket, stream, req, &mut rep, stop).await;
            }
        }
        let summary = capture::run(req, &mut rep, stop).await?;
        match (args.json, args.log_format) {
            (true, _) => {}
            (false, cli::LogFormat::Json) => tracing::info!(
                capture = %summary.dir.display(),
                material = summary.material.as_ref().map(|m| m.display().to_string()),
                "capture finished"
            ),
            (false, cli::LogFormat::Text) => {
                eprintln!("capture: {}", summary.dir.display());
                if let Some(m) = &summary.material {
                    eprintln!("material: {}", m.display());
                }
            }
        }
        Ok(0)
    });
    // Do not wait for blocking work a stop abandoned (a fitter thread
    // finishing its stage): everything that matters was awaited above.
    rt.shutdown_background();
    match result {
        Ok(code) => ExitCode::from(code as u8),
        Err(e) => {
            let code = cli::exit::code(&e);
            rep.emit(cli::progress::Event::Error { message: format!("{e:#}") });
            ExitCode::from(code as u8)
        }
    }
}

#[cfg(target_os = "linux")]
fn list_cameras(json: bool) -> ExitCode {
    match rig::camera::discover::list_cameras() {
        Ok(cams) => {
            if json {
                println!("{}", serde_json::json!({ "cameras": cams }));
            } else {
                print!("{}", rig::camera::discover::render_listing(&cams));
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(cli::exit::FAILED as u8)
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn list_cameras(_json: bool) -> ExitCode {
    eprintln!("error: camera listing needs Linux (V4L2)");
    ExitCode::from(cli::exit::FAILED as u8)
}
