//! Opening the rig's devices: the simulated rig (the emulated MCU on a real
//! pseudo-terminal, driven by the real serial driver, and the simulated
//! camera) or the hardware named in the rig file.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use material::SvBrdf;
use rig::mcu::{PortLocator, Rig, RigSettings, SerialConnector};
use setup::RigGeometry;
use sim::camera::{CameraTiming, LedTruth, SensorModel, SimCamera, SimCameraConfig};
use sim::{FaultSpec, McuConfig, SimMcu, World};

use crate::paths;
use crate::rigfile::RigFile;

/// The simulated rig, running in this process.
pub struct SimRig {
    pub mcu: SimMcu,
    pub rig: Rig<SerialConnector>,
    pub camera: SimCamera,
    pub e_per_dn: f32,
    pub link: PathBuf,
}

impl std::fmt::Debug for SimRig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimRig").field("link", &self.link).finish()
    }
}

/// The emulated MCU's configuration for a rig geometry and time scale.
pub fn mcu_config(g: &RigGeometry, time_scale: f64) -> McuConfig {
    McuConfig {
        n_leds: g.bar.n_leds,
        travel_min_um: (g.gantry.travel_min_mm * 1000.0).round() as i32,
        travel_max_um: (g.gantry.travel_max_mm * 1000.0).round() as i32,
        switch_min_um: (g.gantry.travel_min_mm * 1000.0).round() as i32 - 5_000,
        profile: sim::world::MotionProfile {
            speed_um_s: g.gantry.speed_mm_s as f64 * 1000.0,
            accel_um_s2: g.gantry.accel_mm_s2 as f64 * 1000.0,
        },
        homing_speed_um_s: g.gantry.homing_speed_mm_s as f64 * 1000.0,
        settle_ms: g.gantry.settle_ms as f64,
        time_scale,
        ..McuConfig::default()
    }
}

/// The driver's expectations of motion, scaled like the emulator.
pub fn rig_settings(g: &RigGeometry, time_scale: f64, led_current_ma: u16) -> RigSettings {
    let k = time_scale.max(1e-6);
    RigSettings {
        led_current_ma,
        speed_um_s: g.gantry.speed_mm_s as f64 * 1000.0 / k,
        accel_um_s2: g.gantry.accel_mm_s2 as f64 * 1000.0 / (k * k),
        settle_ms: g.gantry.settle_ms as f64 * k,
        homing_speed_um_s: g.gantry.homing_speed_mm_s as f64 * 1000.0 / k,
        ..RigSettings::default()
    }
}

/// Start the simulated rig rendering `material` and connect the serial
/// driver to it through a pseudo-terminal.
pub async fn open_sim(
    rf: &RigFile,
    geometry: &RigGeometry,
    material: Arc<dyn SvBrdf>,
    faults: &FaultSpec,
) -> Result<SimRig> {
    let scale = if rf.sim.realtime { 1.0 } else { rf.sim.time_scale.max(0.0) as f64 };
    let dir = paths::runtime_dir();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    static COUNTER: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let link = dir.join(format!("sim-mcu-{}-{n}", std::process::id()));
    let world = World::new();
    let mcfg = mcu_config(geometry, scale);
    let rest_um = mcfg.rest_um;
    let mcu = SimMcu::spawn_pty(mcfg, faults.clone(), world.clone(), Some(link.clone()))
        .await
        .context("cannot start the simulated rig's microcontroller")?;
    let sensor = SensorModel::default();
    let e_per_dn = sensor.e_per_dn();
    let timing = if rf.sim.realtime {
        CameraTiming::RealTime { fps: rf.sim.fps, readout_ms: 4.0 }
    } else {
        CameraTiming::Fast { time_scale: 0.0 }
    };
    let cfg = SimCameraConfig {
        geometry: geometry.clone(),
        sensor,
        leds: LedTruth::realistic(geometry.bar.n_leds, rf.sim.seed),
        timing,
        seed: rf.sim.seed,
        faults: faults.clone(),
        rest_um,
    };
    let camera = tokio::task::block_in_place(|| SimCamera::new(cfg, material, world));
    let mut settings = rig_settings(geometry, scale, rf.led_current_ma);
    if !rf.sim.realtime {
        // A pseudo-terminal answers in about 0.1 ms.
        settings.reply_timeout = Duration::from_millis(10);
        settings.move_done_slack = Duration::from_millis(50);
    }
    let connector = SerialConnector {
        locator: PortLocator::Path { path: link.clone() },
        baud: rf.serial.as_ref().map_or(1_000_000, |s| s.baud),
    };
    let rig = Rig::open(connector, settings).await.context("cannot talk to the simulated rig")?;
    Ok(SimRig { mcu, rig, camera, e_per_dn, link })
}
