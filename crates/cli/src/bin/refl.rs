//! `refl`: everything but the operator's capture.

use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};

/// Fit, inspect and serve reflectance captures.
#[derive(Debug, Parser)]
#[command(name = "refl", version)]
struct Args {
    #[command(subcommand)]
    cmd: Cmd,
    /// Log lines as text or as JSON objects (for the journal).
    #[arg(long, global = true, value_enum, default_value = "text")]
    log_format: cli::LogFormat,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Fit (or refit) a stored capture: writes DIR/material and DIR/report.json.
    Fit {
        /// Capture directory.
        dir: std::path::PathBuf,
        /// Use another quality preset's fitting knobs than the capture's.
        #[arg(long)]
        quality: Option<String>,
        /// Fit a capture that is missing planned shots (interrupted and not
        /// resumed); the material and report are marked partial.
        #[arg(long)]
        partial: bool,
        /// Fit only tile K (from 0) of N: read every frame, keep and fit the
        /// points of the K-th of N runs of the grid, and write
        /// DIR/tiles/K-of-N.tile with a done marker. Tiles run at once, on
        /// one machine or many sharing DIR; `--merge` then finishes the fit.
        #[arg(long, value_name = "K/N", conflicts_with = "merge")]
        tile: Option<cli::tiles::Tile>,
        /// Finish a fit made in tiles (`--tile`): the stages that need every
        /// point, then DIR/material and DIR/report.json as a whole `refl fit`
        /// writes them; the tiles are removed afterwards.
        #[arg(long)]
        merge: bool,
    },
    /// Score a capture's fitted material: renders under novel conditions
    /// against ground truth (simulated captures), NDF errors, and hold-out
    /// prediction of every 8th light (any capture).
    Eval {
        /// Capture directory.
        dir: std::path::PathBuf,
        /// Print one JSON object to stdout.
        #[arg(long)]
        json: bool,
        /// Render size (pixels per side).
        #[arg(long, default_value_t = 128)]
        px: u32,
        /// Rays per pixel side: each rendered pixel is the mean of N x N
        /// rays spread evenly over it (default: the evaluation's own,
        /// `assess::eval::RENDER_SUBPIXELS`).
        #[arg(long, value_name = "N")]
        subpixels: Option<u32>,
        /// Skip the hold-out refit.
        #[arg(long)]
        no_holdout: bool,
        /// Score the NDF on observed cells only where this capture and
        /// capture DIR both observed (comparing two rigs or settings on the
        /// same half vectors; same point and table grids).
        #[arg(long, value_name = "DIR")]
        observed_like: Option<std::path::PathBuf>,
    },
    /// Render a fitted material with one of its models to an image
    /// (`.exr`: linear radiance; otherwise PNG at automatic exposure).
    Render {
        /// A material directory, or a capture directory holding `material/`.
        dir: std::path::PathBuf,
        /// Model: tabulated (synthesized when synthesis ran), partial, auto,
        /// or an analytic fit's name (ward_iso, ward_aniso, ggx_aniso, ...).
        #[arg(long, default_value = "tabulated")]
        model: String,
        /// Lighting: point:ELEV,AZ, directional:ELEV,AZ or sky:ELEV,AZ (degrees).
        #[arg(long, default_value = "point:50,250")]
        light: String,
        /// Camera: POLAR,AZIMUTH in degrees, looking at the sample centre.
        #[arg(long, default_value = "35,90")]
        camera: String,
        /// Image side in pixels.
        #[arg(long, default_value_t = 256)]
        px: u32,
        /// Output file.
        #[arg(long, short)]
        out: std::path::PathBuf,
    },
    /// Summarise a material: grid, flags, model choice and the spread of
    /// every fitted parameter.
    Inspect {
        /// A material directory, or a capture directory holding `material/`.
        dir: std::path::PathBuf,
        /// Print one JSON object to stdout.
        #[arg(long)]
        json: bool,
    },
    /// The headless capture service for a rig PC: accepts capture jobs on a
    /// Unix socket (owner and group only), runs one at a time, streams
    /// progress; systemd Type=notify with watchdog. `capture` uses it when
    /// it runs. With --status or --cancel, asks a running daemon instead.
    Daemon {
        /// Socket path (default: $REFLECTOMETER_SOCKET, systemd's
        /// $RUNTIME_DIRECTORY/daemon.sock, or the user's runtime directory).
        #[arg(long)]
        socket: Option<std::path::PathBuf>,
        /// Print what the running daemon is doing.
        #[arg(long, conflicts_with = "cancel")]
        status: bool,
        /// Stop the running daemon's capture (LEDs off, frames kept).
        #[arg(long)]
        cancel: bool,
        /// Also serve the rig's web page on ADDR (default 127.0.0.1:8470,
        /// loopback only): live state, camera view, results, 3D viewer;
        /// starting and cancelling need the token it prints.
        #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = cli::web::DEFAULT_ADDR)]
        http: Option<std::net::SocketAddr>,
        /// npm modules holding three.js for the page's viewer (default: the
        /// source tree's web/node_modules, else /usr/share/reflectometer/web/node_modules).
        #[arg(long, value_name = "DIR", requires = "http")]
        web_modules: Option<std::path::PathBuf>,
    },
    /// The speed/accuracy trade-off: simulated captures of SAMPLE at several
    /// settings, each fitted and scored; writes DIR/tradeoff.json and
    /// DIR/tradeoff.png (the rig's capture time plus the fit's, against
    /// error; Pareto front marked).
    Tradeoff {
        sample: String,
        #[arg(long)]
        out: std::path::PathBuf,
        /// Comma-separated settings (fast, fast-16-steps, fast-all-leds,
        /// balanced-no-synthesis, balanced-per-point, balanced,
        /// balanced-ndf-24, best).
        #[arg(long, default_value = assess::tradeoff::DEFAULT_SETTINGS)]
        settings: String,
        /// Only redraw DIR/tradeoff.png from DIR/tradeoff.json.
        #[arg(long)]
        replot: bool,
    },
    /// Import an RGL material-database file (.bsdf, isotropic) as a
    /// homogeneous material: its measured NDF as the reference table, the
    /// diffuse and specular albedo and Fresnel index fitted to its BRDF.
    /// `capture --sim-material DIR` then scans it.
    ImportRgl(ImportArgs),
    /// Export a fitted material to glTF 2.0 (anisotropic GGX through
    /// KHR_materials_anisotropy, with textures) for ordinary renderers.
    ExportGltf {
        /// A material directory, or a capture directory holding `material/`.
        dir: std::path::PathBuf,
        /// Output `.gltf` (textures and buffer are written beside it).
        #[arg(long, short)]
        out: std::path::PathBuf,
    },
    /// Import a MERL BRDF database file (.binary) as a homogeneous
    /// material: the NDF from its retro-reflection slice, the diffuse and
    /// specular albedo and Fresnel index fitted to the whole BRDF.
    ImportMerl(ImportArgs),
    /// Write a capture's calibrated samples as NumPy arrays (.npz): light
    /// and view directions in the local frame, the measured BRDF per
    /// channel, weights, flags, each point's position (arrays listed in
    /// MATERIAL.md). The frames are replayed through the fitter's ingest.
    ExportSamples {
        /// Capture directory.
        dir: std::path::PathBuf,
        /// Output `.npz` (a new file; an existing one is refused).
        #[arg(long, short)]
        out: std::path::PathBuf,
        /// Every N-th point along each axis of the grid.
        #[arg(long, default_value_t = 1)]
        stride: u32,
    },
    /// Evaluate one point's BRDF: reads lines `ix iy iz ox oy oz` (unit
    /// directions toward the light and the viewer, local frame) on stdin
    /// and prints `r g b` for each.
    Brdf {
        /// A material directory, or a capture directory holding `material/`.
        dir: std::path::PathBuf,
        /// The grid point, `COL,ROW` (row 0 the sample's +y edge).
        #[arg(long)]
        point: String,
        /// Model: tabulated, partial, auto or an analytic fit's name.
        #[arg(long, default_value = "tabulated")]
        model: String,
    },
    /// Print performance figures (see each benchmark's --help).
    Bench {
        #[command(subcommand)]
        which: BenchCmd,
    },
    /// Start the emulated rig microcontroller on a pseudo-terminal (or on
    /// a serial device with --device) and print its device path.
    SimMcu {
        /// Faults to inject (see `capture --help`).
        #[arg(long, default_value = "")]
        faults: String,
        /// Also maintain a stable symlink to the device here.
        #[arg(long, conflicts_with = "device")]
        link: Option<std::path::PathBuf>,
        /// Answer on this existing tty instead of a pseudo-terminal: the
        /// device side of a real serial link, e.g. a USB gadget's
        /// /dev/ttyGS0 (scripts/vm-test.sh).
        #[arg(long, value_name = "TTY")]
        device: Option<std::path::PathBuf>,
        /// Mechanical time scale (1 = real time).
        #[arg(long, default_value_t = 1.0)]
        time_scale: f64,
    },
}

/// What `import-rgl` and `import-merl` take.
#[derive(Debug, clap::Args)]
struct ImportArgs {
    file: std::path::PathBuf,
    /// Material directory to create (new or empty).
    #[arg(long)]
    out: std::path::PathBuf,
    /// Replace the material already in --out (only a material: a directory
    /// holding anything else is never touched).
    #[arg(long)]
    replace: bool,
    /// NDF table rings (the table is RINGS x 3*RINGS cells).
    #[arg(long, default_value_t = 32)]
    ndf_theta: u32,
    /// Side of the (square) sample, mm.
    #[arg(long, default_value_t = 100.0)]
    width_mm: f32,
}

#[derive(Debug, Subcommand)]
enum BenchCmd {
    /// Where the fitter's error comes from: a synthetic capture of SAMPLE
    /// at a preset's plan fitted as captured, without noise, and with each
    /// resolution knob loosened; NDF and BRDF errors against the truth per
    /// row.
    Budget {
        #[arg(long, default_value = "satin")]
        sample: String,
        /// A stored material to budget instead of a built-in one (`refl
        /// import-rgl` or `refl import-merl` output, as `capture
        /// --sim-material` scans it); SAMPLE then only names it.
        #[arg(long, value_name = "DIR")]
        sim_material: Option<std::path::PathBuf>,
        #[arg(long, default_value = "fast")]
        quality: String,
        /// Also write the rows as JSON to this file.
        #[arg(long)]
        json: Option<std::path::PathBuf>,
        /// Only the rows whose name contains this text (e.g. "pooled").
        #[arg(long, value_name = "TEXT")]
        rows: Option<String>,
    },
    /// The fitter's stages (seconds, points/s) and peak memory on a
    /// synthetic capture. Default: the balanced preset's size (96 x 96
    /// points, 64 steps x 40 LEDs), the per-point fit and synthesis. The
    /// talk's scale: --points 800 (2,560 lights). Every stage a capture's
    /// fit runs: --preset balanced.
    Fit {
        #[arg(long, default_value = "satin")]
        sample: String,
        /// Run every stage of this quality preset (synthesis, pooling,
        /// analytic fits, model choice) with its fit settings; its grid,
        /// steps, LED stride and NDF table unless given.
        #[arg(long, value_name = "QUALITY", conflicts_with = "no_synthesis")]
        preset: Option<String>,
        /// Points per side [default: 96, or the preset's grid].
        #[arg(long)]
        points: Option<u32>,
        /// Gantry steps (times 40 LEDs / --led-stride lights) [default: 64,
        /// or the preset's].
        #[arg(long)]
        steps: Option<u32>,
        /// [default: 1, or the preset's]
        #[arg(long)]
        led_stride: Option<u32>,
        /// NDF table rings (the table is RINGS x 3*RINGS cells) [default:
        /// 16, or the preset's].
        #[arg(long)]
        ndf_theta: Option<u32>,
        /// Stop after the per-point fit (no synthesis, no refit).
        #[arg(long)]
        no_synthesis: bool,
    },
    /// A capture on the simulated rig in real time: wall time against the
    /// physical limit (frames x frame period + gantry moves and settling).
    Realtime {
        #[arg(long, default_value = "satin")]
        sample: String,
        #[arg(long, default_value_t = 8)]
        steps: u32,
        #[arg(long, default_value_t = 1)]
        led_stride: u8,
        #[arg(long, default_value_t = 30.0)]
        fps: f32,
    },
    /// Simulated camera frames per second at --px (256 and 800 are the
    /// issue's sizes).
    Camera {
        #[arg(long, default_value = "satin")]
        sample: String,
        #[arg(long, default_value_t = 256)]
        px: u32,
        #[arg(long, default_value_t = 50)]
        frames: u32,
    },
    /// The serial protocol over a pseudo-terminal: round trips per second
    /// and the driver's time per LED firing.
    Protocol {
        #[arg(long, default_value_t = 2000)]
        n: u32,
    },
    /// The accelerated synthesis's time at scale (default: the talk's
    /// 640,000 points and 1,000 rotation angles) on partial tables made
    /// directly from a built-in material's NDFs.
    SynthesisScale {
        #[arg(long, default_value = "satin")]
        sample: String,
        #[arg(long, default_value_t = 640_000)]
        points: usize,
        #[arg(long, default_value_t = 1000)]
        clusters: u32,
        #[arg(long, default_value_t = 1000)]
        rotations: u32,
        /// Half-angle of the observed cone, degrees.
        #[arg(long, default_value_t = 25.0)]
        cone_deg: f32,
    },
    /// Microfacet synthesis: brute force, clustered and accelerated search
    /// on the same partial tables (time and NDF error against ground truth).
    Synthesis {
        #[arg(long, default_value = "satin")]
        sample: String,
        /// Points per side (N = points^2).
        #[arg(long, default_value_t = 64)]
        points: u32,
        #[arg(long, default_value_t = 48)]
        steps: u32,
        /// Comma-separated: brute, clustered, accelerated.
        #[arg(long, default_value = "brute,clustered,accelerated")]
        modes: String,
        /// k-means clusters (default N / 100, 8 to 1000).
        #[arg(long)]
        clusters: Option<u32>,
        /// Rotation angles searched (default: the synthesis's, 96).
        #[arg(long)]
        rotations: Option<u32>,
        /// Nearest (cluster, rotation) pairs looked up per point by the
        /// accelerated search (default: the synthesis's, 48).
        #[arg(long)]
        neighbours: Option<u32>,
    },
}

/// `refl import-rgl` and `refl import-merl`.
fn import(rgl: bool, a: &ImportArgs) -> anyhow::Result<()> {
    let ImportArgs { file, out, replace, ndf_theta, width_mm } = a;
    let (ndf_theta, width_mm) = (*ndf_theta, *width_mm);
    let mode = if *replace { material::WriteMode::Replace } else { material::WriteMode::New };
    let grid = brdf::ndf::NdfGrid::new(ndf_theta, 3 * ndf_theta)
        .map_err(|e| cli::usage(anyhow::anyhow!("--ndf-theta {ndf_theta}: {e}")))?;
    if !(width_mm.is_finite() && width_mm > 0.0 && width_mm <= 2000.0) {
        return Err(cli::usage(anyhow::anyhow!("--width-mm {width_mm}: expected above 0 and at most 2000")));
    }
    let name = file.file_stem().map_or("imported".into(), |s| s.to_string_lossy().into_owned());
    let (m, summary) = if rgl {
        let b = material::rgl::RglBrdf::read(file)?;
        tokio::task::block_in_place(|| material::rgl::import(&b, &name, grid, width_mm))
    } else {
        let b = material::merl::MerlBrdf::read(file)?;
        tokio::task::block_in_place(|| material::merl::import(&b, &name, grid, width_mm))
    };
    material::write(out, &m, mode).with_context(|| format!("writing {}", out.display()))?;
    println!("{}", serde_json::to_string(&summary)?);
    Ok(())
}

/// A benchmark's blocking work, abandoned at the first stop signal (Ctrl-C,
/// SIGTERM, SIGHUP): a benchmark stores nothing, so there is nothing to
/// finish, and `main` does not wait for the abandoned thread.
async fn until_stopped<T: Send + 'static>(
    stop: &tokio::sync::watch::Receiver<bool>,
    work: impl FnOnce() -> anyhow::Result<T> + Send + 'static,
) -> anyhow::Result<T> {
    let job = tokio::task::spawn_blocking(work);
    let mut stop = stop.clone();
    tokio::select! {
        r = job => r.context("the benchmark's thread failed")?,
        Ok(_) = stop.wait_for(|s| *s) => Err(cli::Abandoned("the benchmark").into()),
    }
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
    let args_log_format = args.log_format;
    cli::init_logging(args_log_format);
    // The commands whose work is what they print (see
    // `cli::quiet_on_closed_stdout`); not the rig benchmarks, which talk to
    // an emulated microcontroller.
    let prints_a_report = match &args.cmd {
        Cmd::Inspect { .. } | Cmd::Brdf { .. } => true,
        Cmd::Bench { which } => !matches!(which, BenchCmd::Realtime { .. } | BenchCmd::Protocol { .. }),
        _ => false,
    };
    if prints_a_report {
        cli::quiet_on_closed_stdout();
    }
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let r: anyhow::Result<()> = rt.block_on(async {
        let stop = cli::stop_on_signals()?;
        match args.cmd {
            Cmd::Fit { dir, quality, partial, tile, merge } => {
                let mut rep = cli::progress::Reporter::auto(false);
                let q = match quality {
                    Some(n) => {
                        Some(config::preset(&n).ok_or_else(|| cli::usage(anyhow::anyhow!("unknown quality '{n}'")))?)
                    }
                    None => None,
                };
                let m = match (tile, merge) {
                    (Some(tile), _) => cli::tiles::fit_tile(&dir, tile, q, partial, &mut rep, &stop).await?,
                    (None, true) => cli::tiles::merge(&dir, q, partial, &mut rep, &stop).await?,
                    (None, false) => cli::output::refit(&dir, q, partial, &mut rep, &stop).await?,
                };
                println!("{}", m.display());
                Ok(())
            }
            Cmd::Eval { dir, json, px, subpixels, no_holdout, observed_like } => {
                if subpixels.is_some_and(|n| !(1..=16).contains(&n)) {
                    return Err(cli::usage(anyhow::anyhow!("--subpixels: expected 1 to 16")));
                }
                let mut rep = cli::progress::Reporter::new(if json {
                    cli::progress::Mode::Silent
                } else {
                    cli::progress::Mode::Plain
                });
                let opts = assess::eval::EvalOptions {
                    render_px: px,
                    render_subpixels: subpixels.unwrap_or(assess::eval::RENDER_SUBPIXELS),
                    holdout: !no_holdout,
                    observed_like,
                    ..Default::default()
                };
                let ev = tokio::task::block_in_place(|| assess::eval::evaluate(&dir, &opts, &mut rep))?;
                println!("{}", if json { serde_json::to_string(&ev)? } else { serde_json::to_string_pretty(&ev)? });
                Ok(())
            }
            Cmd::Render { dir, model, light, camera, px, out } => {
                let dir = if dir.join("material").is_dir() { dir.join("material") } else { dir };
                if !(8..=4096).contains(&px) {
                    return Err(cli::usage(anyhow::anyhow!("--px {px}: expected 8 to 4096")));
                }
                let light = assess::renders::Lighting::parse(&light).map_err(cli::usage)?;
                let camera =
                    assess::renders::parse_pair(&camera).map_err(|e| cli::usage(anyhow::anyhow!("--camera: {e}")))?;
                let m =
                    std::sync::Arc::new(material::read(&dir).with_context(|| format!("reading {}", dir.display()))?);
                assess::renders::model_by_name(&m, &model).map_err(cli::usage)?;
                let scene = assess::renders::scene(camera, light, px);
                tokio::task::block_in_place(|| assess::renders::render_to_file(m, &model, &scene, &out))?;
                println!("{}", out.display());
                Ok(())
            }
            Cmd::Inspect { dir, json } => {
                let dir = if dir.join("material").is_dir() { dir.join("material") } else { dir };
                let i = assess::inspect::inspect(&dir)?;
                if json {
                    println!("{}", serde_json::to_string(&i)?);
                } else {
                    assess::inspect::print(&i);
                }
                Ok(())
            }
            Cmd::Daemon { socket, status, cancel, http, web_modules } => {
                if status || cancel {
                    let socket = match socket {
                        Some(s) => s,
                        None => cli::daemon::connect().await?.map(|(p, _)| p).ok_or_else(|| {
                            anyhow::anyhow!(
                                "no daemon is running (tried {})",
                                cli::daemon::client_sockets()
                                    .iter()
                                    .map(|p| p.display().to_string())
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            )
                        })?,
                    };
                    let req = if cancel { cli::daemon::Request::Cancel } else { cli::daemon::Request::Status };
                    println!("{}", cli::daemon::ask(&socket, &req).await?);
                    return Ok(());
                }
                let socket = socket.unwrap_or_else(cli::daemon::default_socket);
                let http = http.map(|addr| cli::daemon::Http { addr, modules: cli::web::find_modules(web_modules) });
                cli::daemon::serve(&socket, http, stop).await
            }
            Cmd::Tradeoff { sample, out, settings, replot } => {
                let mut rep = cli::progress::Reporter::new(cli::progress::Mode::Plain);
                let rows = if replot {
                    assess::tradeoff::replot(&out)?
                } else {
                    tokio::task::block_in_place(|| assess::tradeoff::run(&sample, &out, &settings, &mut rep))?
                };
                println!(
                    "{:24} {:>9} {:>8} {:>9} {:>8} {:>8}  pareto",
                    "setting", "capture_s", "fit_s", "memory_mb", "render", "ndf"
                );
                for r in &rows {
                    println!(
                        "{:24} {:9.1} {:8.1} {:9.0} {:8.4} {:8.4}  {}",
                        r.setting,
                        r.capture_seconds,
                        r.fit_seconds,
                        r.peak_memory_mb.unwrap_or(f64::NAN),
                        r.render_rel_rmse.unwrap_or(f64::NAN),
                        r.ndf_rel_l2_full.unwrap_or(f64::NAN),
                        if r.pareto { "*" } else { "" }
                    );
                }
                println!("{}", out.join("tradeoff.png").display());
                Ok(())
            }
            Cmd::ImportRgl(a) => import(true, &a),
            Cmd::ImportMerl(a) => import(false, &a),
            Cmd::ExportGltf { dir, out } => {
                let dir = if dir.join("material").is_dir() { dir.join("material") } else { dir };
                let m = material::read(&dir).with_context(|| format!("reading {}", dir.display()))?;
                for f in assess::gltf::export(&m, &out)? {
                    println!("{}", f.display());
                }
                Ok(())
            }
            Cmd::ExportSamples { dir, out, stride } => {
                if out.exists() {
                    return Err(cli::usage(anyhow::anyhow!(
                        "{} exists; nothing was written (remove it or choose another name)",
                        out.display()
                    )));
                }
                if stride == 0 {
                    return Err(cli::usage(anyhow::anyhow!("--stride must be at least 1")));
                }
                let mut rep = cli::progress::Reporter::auto(false);
                let e = tokio::task::block_in_place(|| assess::export::export_samples(&dir, &out, stride, &mut rep))?;
                println!(
                    "{}: {} points x {} lights, {} usable samples, {:.1} MB",
                    e.file.display(),
                    e.points,
                    e.lights,
                    e.usable,
                    e.bytes as f64 / 1e6
                );
                Ok(())
            }
            Cmd::Brdf { dir, point, model } => {
                use std::io::BufRead;
                let dir = if dir.join("material").is_dir() { dir.join("material") } else { dir };
                let m =
                    std::sync::Arc::new(material::read(&dir).with_context(|| format!("reading {}", dir.display()))?);
                let choice = assess::renders::model_by_name(&m, &model).map_err(cli::usage)?;
                let (c, r) = assess::renders::parse_pair(&point)
                    .map_err(|e| cli::usage(anyhow::anyhow!("--point: {e}")))
                    .and_then(|(c, r)| {
                        if c.fract() == 0.0 && r.fract() == 0.0 {
                            Ok((c as i64, r as i64))
                        } else {
                            Err(cli::usage(anyhow::anyhow!("--point {point}: COL,ROW are whole numbers")))
                        }
                    })?;
                if c < 0 || r < 0 || c >= m.grid.cols as i64 || r >= m.grid.rows as i64 {
                    return Err(cli::usage(anyhow::anyhow!(
                        "--point {point}: the grid is {} x {} (COL,ROW from 0)",
                        m.grid.cols,
                        m.grid.rows
                    )));
                }
                let view = material::MaterialView::new(m.clone(), choice)
                    .ok_or_else(|| cli::usage(anyhow::anyhow!("the material has no model '{model}'")))?;
                let f = view.point((r * m.grid.cols as i64 + c) as usize);
                for (k, line) in std::io::stdin().lock().lines().enumerate() {
                    let line = line?;
                    let v: Vec<f32> =
                        line.split_whitespace().map(str::parse).collect::<Result<_, _>>().map_err(|e| {
                            cli::usage(anyhow::anyhow!("line {}: {e}: expected ix iy iz ox oy oz", k + 1))
                        })?;
                    let [ix, iy, iz, ox, oy, oz] = v[..] else {
                        return Err(cli::usage(anyhow::anyhow!(
                            "line {}: {} numbers; expected ix iy iz ox oy oz",
                            k + 1,
                            v.len()
                        )));
                    };
                    let rgb = brdf::Brdf::eval(&f, glam::Vec3::new(ix, iy, iz), glam::Vec3::new(ox, oy, oz));
                    println!("{:e} {:e} {:e}", rgb.x, rgb.y, rgb.z);
                }
                Ok(())
            }
            Cmd::Bench { which } => match which {
                BenchCmd::Realtime { sample, steps, led_stride, fps } => {
                    cli::bench::realtime(&sample, steps, led_stride, fps).await
                }
                BenchCmd::Camera { sample, px, frames } => {
                    until_stopped(&stop, move || assess::bench::camera(&sample, px, frames).map(|_| ())).await
                }
                BenchCmd::Protocol { n } => assess::bench::protocol(n).await,
                BenchCmd::Budget { sample, sim_material, quality, json, rows } => {
                    let q = config::preset(&quality)
                        .ok_or_else(|| cli::usage(anyhow::anyhow!("unknown quality '{quality}'")))?;
                    let rows = until_stopped(&stop, move || {
                        assess::budget::run(&sample, sim_material.as_deref(), &q, rows.as_deref())
                    })
                    .await?;
                    if let Some(p) = json {
                        std::fs::write(&p, serde_json::to_vec_pretty(&rows)?)
                            .with_context(|| format!("cannot write {}", p.display()))?;
                    }
                    Ok(())
                }
                BenchCmd::SynthesisScale { sample, points, clusters, rotations, cone_deg } => {
                    until_stopped(&stop, move || {
                        assess::bench::synthesis_scale(&sample, points, clusters, rotations, cone_deg)
                    })
                    .await
                }
                BenchCmd::Fit { sample, preset, points, steps, led_stride, ndf_theta, no_synthesis } => {
                    use assess::bench::BenchStages;
                    let run = match preset {
                        Some(n) => BenchStages::Preset(Box::new(config::preset(&n).ok_or_else(|| {
                            cli::usage(anyhow::anyhow!(
                                "unknown quality '{n}': use one of {}",
                                config::PRESETS.join(", ")
                            ))
                        })?)),
                        None if no_synthesis => BenchStages::PointsOnly,
                        None => BenchStages::Synthesis,
                    };
                    let q = match &run {
                        BenchStages::Preset(q) => Some(q.as_ref()),
                        _ => None,
                    };
                    let points = points.or(q.map(|q| q.grid)).unwrap_or(96);
                    let steps = steps.or(q.map(|q| q.steps)).unwrap_or(64);
                    let led_stride = led_stride.or(q.map(|q| q.led_stride as u32)).unwrap_or(1);
                    let ndf_theta = ndf_theta.or(q.map(|q| q.fit.grid.n_theta)).unwrap_or(16);
                    until_stopped(&stop, move || {
                        assess::bench::fit(&sample, points, steps, led_stride, ndf_theta, &run)
                    })
                    .await
                }
                BenchCmd::Synthesis { sample, points, steps, modes, clusters, rotations, neighbours } => {
                    let modes = assess::bench::parse_modes(&modes)?;
                    until_stopped(&stop, move || {
                        assess::bench::synthesis(&sample, points, steps, &modes, clusters, (rotations, neighbours))
                    })
                    .await
                }
            },
            Cmd::SimMcu { faults, link, device, time_scale } => {
                let spec = sim::FaultSpec::parse(&faults).map_err(|e| cli::usage(anyhow::anyhow!("--faults: {e}")))?;
                let cfg = sim::McuConfig::for_geometry(&setup::RigGeometry::default(), time_scale);
                let mcu = match device {
                    Some(d) => sim::SimMcu::spawn_device(cfg, spec, sim::World::new(), &d).await?,
                    None => sim::SimMcu::spawn_pty(cfg, spec, sim::World::new(), link).await?,
                };
                let path = mcu.device_path().ok_or_else(|| anyhow::anyhow!("the emulator has no device"))?;
                println!("{}", path.display());
                eprintln!("emulated rig MCU on {}; Ctrl-C to stop", path.display());
                let mut stop = stop;
                let _ = stop.wait_for(|s| *s).await;
                mcu.stop().await?;
                Ok(())
            }
        }
    });
    // Do not wait for blocking work a stop abandoned (a fitter thread
    // finishing its stage): everything that matters was awaited above.
    rt.shutdown_background();
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            match args_log_format {
                cli::LogFormat::Json => tracing::error!("{e:#}"),
                cli::LogFormat::Text => eprintln!("error: {e:#}"),
            }
            ExitCode::from(cli::exit::code(&e) as u8)
        }
    }
}
