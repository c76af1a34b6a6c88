//! `refl`: everything but the operator's capture.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Fit, inspect and serve reflectance captures.
#[derive(Debug, Parser)]
#[command(name = "refl", version)]
struct Args {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Start the emulated rig microcontroller on a pseudo-terminal and print its device path.
    SimMcu {
        /// Faults to inject (see `capture --help`).
        #[arg(long, default_value = "")]
        faults: String,
        /// Also maintain a stable symlink to the device here.
        #[arg(long)]
        link: Option<std::path::PathBuf>,
        /// Mechanical time scale (1 = real time).
        #[arg(long, default_value_t = 1.0)]
        time_scale: f64,
    },
}

fn main() -> ExitCode {
    cli::init_logging();
    let args = Args::parse();
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let r: anyhow::Result<()> = rt.block_on(async {
        match args.cmd {
            Cmd::SimMcu { faults, link, time_scale } => {
                let spec = sim::FaultSpec::parse(&faults).map_err(|e| anyhow::anyhow!("--faults: {e}"))?;
                let cfg = cli::session::mcu_config(&setup::RigGeometry::default(), time_scale);
                let mcu = sim::SimMcu::spawn_pty(cfg, spec, sim::World::new(), link).await?;
                let path = mcu.device_path().ok_or_else(|| anyhow::anyhow!("the emulator has no device"))?;
                println!("{}", path.display());
                eprintln!("emulated rig MCU on {}; Ctrl-C to stop", path.display());
                tokio::signal::ctrl_c().await?;
                mcu.stop().await?;
                Ok(())
            }
        }
    });
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
