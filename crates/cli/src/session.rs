//! Opening the rig's devices: the simulated rig (the emulated MCU on a real
//! pseudo-terminal, driven by the real serial driver, and the simulated
//! camera) or the hardware named in the rig file.

use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, anyhow};
use frame::{Frame, MonoNs};
use material::SvBrdf;
use rig::camera::{AppliedSettings, Camera, CameraError, CameraSettings};
use rig::mcu::{PortLocator, Rig, RigSettings, SerialConnector};
use setup::RigGeometry;
use sim::camera::{CameraTiming, LedTruth, SensorModel, SimCamera, SimCameraConfig};
use sim::{FaultSpec, McuConfig, RigTruth, SimMcu, World};

use crate::paths;
use crate::progress::Reporter;
use config::RigFile;

/// An open rig: the serial driver and the camera, and on the simulated rig
/// the emulated microcontroller behind the pseudo-terminal.
pub struct Session {
    pub rig: Rig<SerialConnector>,
    pub camera: RigCamera,
    /// Electrons per DN at unit gain (the sensor model's, or the rig file's).
    pub e_per_dn: f32,
    /// Frames per second asked of the camera.
    pub fps: f32,
    mcu: Option<SimMcu>,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session").field("camera", &self.camera).finish()
    }
}

/// The simulated light bar's warmth (seconds of LED light it has had), kept
/// from one session to the next within a process: the calibration scans and
/// the capture that follows them in one `capture` run, or a daemon's
/// captures back to back, light one physical bar. A new process starts
/// with a cold bar, as the next morning's run would. f64 bits.
static SIM_BAR_ON_S: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

impl Session {
    /// Switch the rig off (LEDs off, motors released) and stop the emulated
    /// microcontroller if there is one.
    pub async fn close(&mut self) {
        if let RigCamera::Sim(c) = &self.camera {
            SIM_BAR_ON_S.store(c.on_time_s().to_bits(), std::sync::atomic::Ordering::Relaxed);
        }
        self.rig.shutdown().await;
        if let Some(mcu) = self.mcu.take() {
            let _ = mcu.stop().await;
        }
    }
}

/// Configure a camera for a scan or a capture and pass on its warnings
/// (non-radiometric format, missing controls) to the operator.
pub async fn configure_camera<C: Camera>(
    camera: &mut C,
    settings: &CameraSettings,
    rep: &mut Reporter,
) -> Result<AppliedSettings> {
    let applied = camera.configure(settings).await.context("cannot configure the camera")?;
    for w in &applied.warnings {
        rep.warn(format!("camera: {w}"));
    }
    Ok(applied)
}

/// The rig's camera: the simulated one or a V4L2 device.
pub enum RigCamera {
    Sim(SimCamera),
    #[cfg(target_os = "linux")]
    V4l2(rig::camera::v4l2::V4l2Camera),
}

impl std::fmt::Debug for RigCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.describe())
    }
}

impl Camera for RigCamera {
    fn describe(&self) -> String {
        match self {
            RigCamera::Sim(c) => c.describe(),
            #[cfg(target_os = "linux")]
            RigCamera::V4l2(c) => c.describe(),
        }
    }

    async fn configure(&mut self, settings: &CameraSettings) -> Result<AppliedSettings, CameraError> {
        match self {
            RigCamera::Sim(c) => c.configure(settings).await,
            #[cfg(target_os = "linux")]
            RigCamera::V4l2(c) => c.configure(settings).await,
        }
    }

    async fn set_exposure(&mut self, exposure_us: u32, gain: f32) -> Result<(), CameraError> {
        match self {
            RigCamera::Sim(c) => c.set_exposure(exposure_us, gain).await,
            #[cfg(target_os = "linux")]
            RigCamera::V4l2(c) => c.set_exposure(exposure_us, gain).await,
        }
    }

    async fn frame_after(&mut self, after: MonoNs, timeout: Duration) -> Result<Frame, CameraError> {
        match self {
            RigCamera::Sim(c) => c.frame_after(after, timeout).await,
            #[cfg(target_os = "linux")]
            RigCamera::V4l2(c) => c.frame_after(after, timeout).await,
        }
    }

    async fn discards(&mut self) -> rig::camera::Discards {
        match self {
            RigCamera::Sim(c) => c.discards().await,
            #[cfg(target_os = "linux")]
            RigCamera::V4l2(c) => c.discards().await,
        }
    }
}

/// Start the simulated rig rendering `material` and connect the serial
/// driver to it through a pseudo-terminal.
pub async fn open_sim(
    rf: &RigFile,
    geometry: &RigGeometry,
    material: Arc<dyn SvBrdf>,
    faults: &FaultSpec,
) -> Result<Session> {
    let scale = if rf.sim.realtime { 1.0 } else { rf.sim.time_scale.max(0.0) as f64 };
    let dir = paths::runtime_dir();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    remove_stale_links(&dir);
    static COUNTER: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let link = dir.join(format!("sim-mcu-{}-{n}", std::process::id()));
    let world = World::new();
    let mcfg = McuConfig::for_geometry(geometry, scale);
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
    let truth = match rf.sim.rig {
        config::SimRig::Ideal => RigTruth::ideal(geometry),
        config::SimRig::Perturbed { seed, .. } => {
            let p = |part: &str| rf.sim.rig.perturbs(part);
            let tol = sim::Tolerances::default().keeping(
                p("camera"),
                p("leds"),
                p("gantry"),
                p("sample"),
                p("sensor"),
                p("drift"),
            );
            RigTruth::drawn(geometry, &tol, seed)
        }
    };
    let cfg = SimCameraConfig {
        truth,
        sensor,
        leds: LedTruth::realistic(geometry.bar.n_leds, rf.sim.seed),
        timing,
        seed: rf.sim.seed,
        faults: faults.clone(),
        rest_um,
    };
    let mut camera = tokio::task::block_in_place(|| SimCamera::new(cfg, material, world));
    camera.set_on_time_s(f64::from_bits(SIM_BAR_ON_S.load(std::sync::atomic::Ordering::Relaxed)));
    let mut settings = RigSettings::for_geometry(geometry, scale, rf.led_current_ma);
    if !rf.sim.realtime {
        // Motion is sped up by the time scale, so a late `MoveDone` is
        // checked for sooner. The reply timeout is the protocol's
        // (`REPLY_TIMEOUT_MS`), as on hardware: the emulator must answer
        // within it like a real controller.
        settings.move_done_slack = Duration::from_millis(50);
    }
    let connector = SerialConnector {
        locator: PortLocator::Path { path: link.clone() },
        baud: rf.serial.as_ref().map_or(1_000_000, |s| s.baud),
    };
    let rig = Rig::open(connector, settings).await.context("cannot talk to the simulated rig")?;
    Ok(Session { rig, camera: RigCamera::Sim(camera), e_per_dn, fps: rf.sim.fps, mcu: Some(mcu) })
}

/// Remove `sim-mcu-PID-N` links left in `dir` by processes that no longer
/// exist (killed with SIGKILL, or by a signal they did not handle).
fn remove_stale_links(dir: &std::path::Path) {
    let Ok(rd) = std::fs::read_dir(dir) else { return };
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = name.strip_prefix("sim-mcu-").and_then(|r| r.split('-').next()?.parse::<i32>().ok()) else {
            continue;
        };
        // SAFETY: kill with signal 0 only checks that the process exists.
        let gone =
            unsafe { libc::kill(pid, 0) } != 0 && std::io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH);
        if gone && e.file_type().is_ok_and(|t| t.is_symlink()) {
            tracing::debug!(link = %e.path().display(), "removing a stale emulator link");
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Open the hardware the rig file names: the microcontroller on its serial
/// port and the V4L2 camera.
pub async fn open_hardware(rf: &RigFile, geometry: &RigGeometry) -> Result<Session> {
    let (Some(serial), Some(cam)) = (&rf.serial, &rf.camera) else {
        return Err(anyhow!("rig '{}' needs [serial] and [camera] sections (see RIGFILE.md)", rf.name));
    };
    let camera = open_v4l2(cam).await?;
    let connector = SerialConnector { locator: serial.locator.clone(), baud: serial.baud };
    let settings = RigSettings::for_geometry(geometry, 1.0, rf.led_current_ma);
    let rig = Rig::open(connector, settings)
        .await
        .with_context(|| format!("cannot talk to rig '{}' on its serial port", rf.name))?;
    Ok(Session { rig, camera, e_per_dn: cam.e_per_dn, fps: cam.fps, mcu: None })
}

#[cfg(target_os = "linux")]
async fn open_v4l2(cam: &config::rigfile::CameraSection) -> Result<RigCamera> {
    use rig::camera::v4l2::{V4l2Camera, V4l2Options};
    let opts = V4l2Options {
        path: cam.device.clone(),
        format: cam.format.clone(),
        gain_unity: cam.gain_unity,
        buffers: cam.buffers.clamp(2, 32),
    };
    let camera = V4l2Camera::open(opts).with_context(|| format!("cannot open the camera {}", cam.device.display()))?;
    Ok(RigCamera::V4l2(camera))
}

#[cfg(not(target_os = "linux"))]
async fn open_v4l2(_: &config::rigfile::CameraSection) -> Result<RigCamera> {
    Err(anyhow!("hardware cameras are V4L2 devices and need Linux"))
}
