//! The V4L2 camera backend, on the `v4l` crate.
//!
//! One worker thread owns the device and its mapped buffers (they are not
//! `Send`); the async [`Camera`] methods send it a request and await the
//! reply. Per session it:
//!
//! - chooses the deepest raw format offered (or the rig file's), resets the
//!   stride and size so no padding survives a format switch, and refuses
//!   MJPG; YUYV is accepted with a warning that it is not radiometric;
//! - sets every control the measurement depends on (auto exposure, auto
//!   gain, auto white balance and exposure priority off; absolute exposure
//!   in 100 us units; gain), because controls persist across opens, then
//!   reads every control back and records what the driver accepted;
//! - drops error-flagged and short buffers, frames exposed before a
//!   control change plus `settle_frames` after it, and frames whose
//!   exposure began before the requested instant (buffer timestamps, which
//!   are `CLOCK_MONOTONIC`, not arrival order);
//! - on `ENODEV` forgets the device and, on the next request, opens the
//!   same path again (the udev link comes back when the camera is
//!   re-plugged) and re-applies the session's settings.

use std::collections::BTreeMap;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use frame::{Frame, FrameFlags, FrameMeta, MonoNs};
use tokio::sync::oneshot;
use v4l::buffer::{Flags as BufFlags, Type as BufType};
use v4l::control::{Control, Description, Type as CtrlType, Value};
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, Format, FourCC};

use super::pixel::{self, PixelFormat};
use super::{AppliedSettings, Camera, CameraError, CameraSettings, FrameFilter, Verdict};

/// V4L2 control ids (linux/v4l2-controls.h).
pub mod cid {
    pub const AUTO_WHITE_BALANCE: u32 = 0x0098_090c;
    pub const EXPOSURE: u32 = 0x0098_0911;
    pub const AUTOGAIN: u32 = 0x0098_0912;
    pub const GAIN: u32 = 0x0098_0913;
    pub const EXPOSURE_AUTO: u32 = 0x009a_0901;
    pub const EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
    pub const EXPOSURE_AUTO_PRIORITY: u32 = 0x009a_0903;
    /// `V4L2_EXPOSURE_MANUAL`, the menu item of `EXPOSURE_AUTO`.
    pub const EXPOSURE_MANUAL: i64 = 1;
}

/// How to open and drive one camera.
#[derive(Clone, Debug)]
pub struct V4l2Options {
    /// Device node, normally the udev link `/dev/reflectometer/camera`.
    pub path: PathBuf,
    /// Pixel format by code (`"Y16"`, `"BA81"`); `None` takes the deepest
    /// raw format offered.
    pub format: Option<String>,
    /// The gain control's value that means unit gain. `None`: the
    /// control's default (its minimum if the default is 0).
    pub gain_unity: Option<i64>,
    /// Mapped buffers (a few frames of slack between requests).
    pub buffers: u32,
}

impl V4l2Options {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self { path: path.into(), format: None, gain_unity: None, buffers: 4 }
    }
}

/// A V4L2 camera. Dropping it stops the stream and closes the device.
#[derive(Debug)]
pub struct V4l2Camera {
    path: PathBuf,
    tx: mpsc::Sender<Request>,
    worker: Option<std::thread::JoinHandle<()>>,
}

enum Request {
    Configure(CameraSettings, oneshot::Sender<Result<AppliedSettings, CameraError>>),
    SetExposure(u32, f32, oneshot::Sender<Result<(), CameraError>>),
    FrameAfter(MonoNs, Duration, oneshot::Sender<Result<Frame, CameraError>>),
    Counters(oneshot::Sender<Counters>),
}

/// Frames the backend dropped, by reason (for tests and the capture log).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    pub delivered: u64,
    pub dropped_error: u64,
    pub dropped_short: u64,
    pub dropped_early: u64,
    pub dropped_settling: u64,
    /// Times the device was opened again after it disappeared.
    pub reopened: u64,
}

impl V4l2Camera {
    /// Open the device now (so a wrong path fails at once, with the path in
    /// the message). Streaming starts at [`Camera::configure`].
    pub fn open(opts: V4l2Options) -> Result<Self, CameraError> {
        let dev = open_device(&opts.path)?;
        let path = opts.path.clone();
        let (tx, rx) = mpsc::channel();
        let worker = std::thread::Builder::new()
            .name("v4l2-camera".into())
            .spawn(move || Worker::new(opts, dev).run(rx))
            .map_err(CameraError::Io)?;
        Ok(Self { path, tx, worker: Some(worker) })
    }

    /// Frames dropped so far, by reason.
    pub async fn counters(&self) -> Counters {
        let (tx, rx) = oneshot::channel();
        if self.tx.send(Request::Counters(tx)).is_err() {
            return Counters::default();
        }
        rx.await.unwrap_or_default()
    }

    async fn ask<T>(
        &self,
        make: impl FnOnce(oneshot::Sender<Result<T, CameraError>>) -> Request,
    ) -> Result<T, CameraError> {
        let (tx, rx) = oneshot::channel();
        let stopped = || CameraError::Gone(format!("{}: the camera worker stopped", self.path.display()));
        self.tx.send(make(tx)).map_err(|_| stopped())?;
        rx.await.map_err(|_| stopped())?
    }
}

impl Drop for V4l2Camera {
    fn drop(&mut self) {
        // Closing the channel ends the worker, which stops the stream.
        let (tx, _) = mpsc::channel();
        drop(std::mem::replace(&mut self.tx, tx));
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

impl Camera for V4l2Camera {
    fn describe(&self) -> String {
        format!("V4L2 camera {}", self.path.display())
    }

    async fn configure(&mut self, settings: &CameraSettings) -> Result<AppliedSettings, CameraError> {
        let s = settings.clone();
        self.ask(|tx| Request::Configure(s, tx)).await
    }

    async fn set_exposure(&mut self, exposure_us: u32, gain: f32) -> Result<(), CameraError> {
        self.ask(|tx| Request::SetExposure(exposure_us, gain, tx)).await
    }

    async fn frame_after(&mut self, after: MonoNs, timeout: Duration) -> Result<Frame, CameraError> {
        self.ask(|tx| Request::FrameAfter(after, timeout, tx)).await
    }

    async fn discards(&mut self) -> super::Discards {
        let c = self.counters().await;
        super::Discards {
            error_flagged: c.dropped_error,
            stale: c.dropped_early,
            settling: c.dropped_settling,
            short: c.dropped_short,
        }
    }
}

fn open_device(path: &Path) -> Result<Device, CameraError> {
    Device::with_path(path).map_err(|e| match e.raw_os_error() {
        Some(libc::ENOENT) | Some(libc::ENODEV) | Some(libc::ENXIO) => {
            CameraError::Gone(format!("no device at {}", path.display()))
        }
        Some(libc::EACCES) | Some(libc::EPERM) => CameraError::Io(io::Error::new(
            e.kind(),
            format!("{}: {e}; add this user to the 'video' group (see udev/README.md)", path.display()),
        )),
        _ => CameraError::Io(io::Error::new(e.kind(), format!("{}: {e}", path.display()))),
    })
}

fn is_gone(e: &io::Error) -> bool {
    matches!(e.raw_os_error(), Some(libc::ENODEV) | Some(libc::ENXIO))
}

fn io_err(path: &Path, what: &str, e: io::Error) -> CameraError {
    if is_gone(&e) {
        CameraError::Gone(format!("{}: {what}: {e}", path.display()))
    } else {
        CameraError::Io(io::Error::new(e.kind(), format!("{}: {what}: {e}", path.display())))
    }
}

/// The stream of mapped buffers. `v4l` panics if stopping fails for any
/// reason but a vanished device; a camera must never take the program down,
/// so the stop is done here first and the drop only unmaps.
struct Streaming {
    stream: v4l::io::mmap::Stream<'static>,
}

impl Drop for Streaming {
    fn drop(&mut self) {
        let _ = v4l::io::traits::Stream::stop(&mut self.stream);
    }
}

/// What one configured session knows about its device.
struct Session {
    dev: Device,
    stream: Option<Streaming>,
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: usize,
    /// Frame period the driver accepted.
    interval: Duration,
    controls: Vec<CtrlInfo>,
    exposure_us: u32,
    gain: f32,
    /// Sequence numbers restart at every STREAMON; this keeps them rising.
    sequence_base: u64,
    last_sequence: u64,
    /// Frames exposed before this instant predate the last control change.
    changed_at: Option<MonoNs>,
}

struct Worker {
    opts: V4l2Options,
    /// Kept between `open` and the first `configure`.
    fresh: Option<Device>,
    session: Option<Session>,
    settings: Option<CameraSettings>,
    filter: FrameFilter,
    counters: Counters,
    /// Where the next session's sequence numbers start.
    next_base: u64,
}

impl Worker {
    fn new(opts: V4l2Options, dev: Device) -> Self {
        Self {
            opts,
            fresh: Some(dev),
            session: None,
            settings: None,
            filter: FrameFilter::new(0),
            counters: Counters::default(),
            next_base: 0,
        }
    }

    fn run(mut self, rx: mpsc::Receiver<Request>) {
        while let Ok(req) = rx.recv() {
            match req {
                Request::Configure(s, tx) => {
                    let r = self.configure(&s);
                    let _ = tx.send(r);
                }
                Request::SetExposure(us, gain, tx) => {
                    let r = self.set_exposure(us, gain);
                    let _ = tx.send(r);
                }
                Request::FrameAfter(after, timeout, tx) => {
                    let r = self.frame_after(after, timeout);
                    let _ = tx.send(r);
                }
                Request::Counters(tx) => {
                    let mut c = self.counters;
                    c.dropped_error += self.filter.dropped_error;
                    c.dropped_early += self.filter.dropped_early;
                    c.dropped_settling += self.filter.dropped_settling;
                    let _ = tx.send(c);
                }
            }
        }
    }

    fn configure(&mut self, s: &CameraSettings) -> Result<AppliedSettings, CameraError> {
        if let Some(old) = self.session.take() {
            self.next_base = old.last_sequence + 1;
        }
        let dev = match self.fresh.take() {
            Some(d) => d,
            None => open_device(&self.opts.path)?,
        };
        let (session, applied) = self.start_session(dev, s, self.next_base)?;
        self.session = Some(session);
        self.settings = Some(s.clone());
        self.filter = FrameFilter::new(s.settle_frames);
        Ok(applied)
    }

    fn start_session(
        &self,
        dev: Device,
        s: &CameraSettings,
        sequence_base: u64,
    ) -> Result<(Session, AppliedSettings), CameraError> {
        let path = &self.opts.path;
        let caps = dev.query_caps().map_err(|e| io_err(path, "query capabilities", e))?;
        let offered: Vec<PixelFormat> = dev
            .enum_formats()
            .map_err(|e| io_err(path, "list formats", e))?
            .iter()
            .map(|d| PixelFormat::from_fourcc(d.fourcc.repr))
            .collect();
        let format = pixel::choose(&offered, self.opts.format.as_deref()).map_err(CameraError::Unsupported)?;
        // Stride and size zero: the driver computes them for this format,
        // so padding from a previous format is not kept.
        let mut want = Format::new(s.width, s.height, FourCC::new(&format.fourcc()));
        want.stride = 0;
        want.size = 0;
        let got = dev.set_format(&want).map_err(|e| io_err(path, "set format", e))?;
        if got.fourcc.repr != format.fourcc() {
            return Err(CameraError::Unsupported(format!(
                "asked for {} but the driver chose {}",
                format.name(),
                super::pixel::fourcc_text(got.fourcc.repr)
            )));
        }
        if (got.width, got.height) != (s.width, s.height) {
            let sizes = super::discover::frame_sizes(&dev, got.fourcc).join(", ");
            return Err(CameraError::Unsupported(format!(
                "the rig's geometry is calibrated for {}x{} but the camera gives {}x{} in {} (sizes it offers: {sizes}); \
                 set [geometry.camera] width/height to one of them and calibrate again",
                s.width,
                s.height,
                got.width,
                got.height,
                format.name().trim_end()
            )));
        }
        let fps = s.fps.max(0.1).round().max(1.0) as u32;
        let interval = match dev.set_params(&v4l::video::capture::Parameters::with_fps(fps)) {
            Ok(p) if p.interval.numerator > 0 && p.interval.denominator > 0 => {
                Duration::from_secs_f64(p.interval.numerator as f64 / p.interval.denominator as f64)
            }
            _ => Duration::from_secs_f64(1.0 / fps as f64),
        };
        let controls = dev.query_controls().unwrap_or_default().iter().map(CtrlInfo::from).collect();
        let mut session = Session {
            dev,
            stream: None,
            format,
            width: got.width,
            height: got.height,
            stride: got.stride as usize,
            interval,
            controls,
            exposure_us: s.exposure_us,
            gain: s.gain,
            sequence_base,
            last_sequence: sequence_base,
            changed_at: None,
        };
        let mut warnings: Vec<String> = format.warning().into_iter().collect();
        let mut recorded = BTreeMap::new();
        self.apply_controls(&mut session, s.exposure_us, s.gain, true, &mut warnings, &mut recorded)?;
        if s.exposure_us as f64 * 1e-6 > interval.as_secs_f64() {
            warnings.push(format!(
                "exposure {} us is longer than the frame interval {:.1} ms; the driver may shorten it",
                s.exposure_us,
                interval.as_secs_f64() * 1e3
            ));
        }
        // Everything else the driver exposes, read back as it is.
        for d in &session.controls {
            if d.flags.contains(v4l::control::Flags::WRITE_ONLY) {
                continue;
            }
            if matches!(
                d.typ,
                CtrlType::Integer | CtrlType::Boolean | CtrlType::Menu | CtrlType::IntegerMenu | CtrlType::Integer64
            ) {
                if let Ok(c) = session.dev.control(d.id) {
                    if let Some(v) = int_value(&c.value) {
                        recorded.entry(format!("driver: {}", d.name)).or_insert(v);
                    }
                }
            }
        }
        let buffers = self.opts.buffers.max(2);
        let stream = v4l::io::mmap::Stream::with_buffers(&session.dev, BufType::VideoCapture, buffers)
            .map_err(|e| io_err(path, "map buffers", e))?;
        session.stream = Some(Streaming { stream });
        session.changed_at = Some(crate::clock::now_mono());
        let applied = AppliedSettings {
            device: path.display().to_string(),
            driver: format!("{} ({}, {})", caps.driver, caps.card, caps.bus),
            format: format.name().trim_end().to_string(),
            width: session.width,
            height: session.height,
            bit_depth: format.bit_depth(),
            layout: Some(format.layout()),
            exposure_us: session.exposure_us,
            gain: session.gain,
            controls: recorded,
            warnings,
        };
        Ok((session, applied))
    }

    /// Set the measurement's controls and read them back. `all` also turns
    /// every automatic mode off (every session; a bracket step only
    /// changes exposure and gain).
    fn apply_controls(
        &self,
        s: &mut Session,
        exposure_us: u32,
        gain: f32,
        all: bool,
        warnings: &mut Vec<String>,
        recorded: &mut BTreeMap<String, i64>,
    ) -> Result<(), CameraError> {
        let path = &self.opts.path;
        let has = |id: u32| s.controls.iter().find(|d| d.id == id).cloned();
        let mut plan: Vec<(&str, CtrlInfo, i64)> = Vec::new();
        if all {
            for (name, id, value) in [
                ("exposure_auto", cid::EXPOSURE_AUTO, cid::EXPOSURE_MANUAL),
                ("exposure_auto_priority", cid::EXPOSURE_AUTO_PRIORITY, 0),
                ("gain_automatic", cid::AUTOGAIN, 0),
                ("white_balance_automatic", cid::AUTO_WHITE_BALANCE, 0),
            ] {
                if let Some(d) = has(id) {
                    plan.push((name, d, value));
                }
            }
        }
        match (has(cid::EXPOSURE_ABSOLUTE), has(cid::EXPOSURE)) {
            (Some(d), _) => plan.push(("exposure_absolute", d, (exposure_us as i64 + 50) / 100)),
            (None, Some(d)) => {
                if all {
                    warnings.push(
                        "the camera has only the generic exposure control, in units its driver chooses; \
                         exposure times are recorded as asked, not as measured"
                            .into(),
                    );
                }
                plan.push(("exposure", d, exposure_us as i64));
            }
            (None, None) => {
                if all {
                    warnings.push("the camera has no exposure control: HDR brackets will not differ".into());
                }
            }
        }
        let unity = has(cid::GAIN).map(|d| self.gain_unity(&d));
        if let (Some(d), Some(unity)) = (has(cid::GAIN), unity) {
            plan.push(("gain", d, (gain as f64 * unity as f64).round() as i64));
        } else if all && gain != 1.0 {
            warnings.push(format!("the camera has no gain control; gain {gain} is ignored"));
        }
        for (_, d, value) in &plan {
            let v = value.clamp(&d.minimum, &d.maximum);
            let v = if d.step > 1 { d.minimum + (v - d.minimum) / d.step as i64 * d.step as i64 } else { *v };
            if d.flags.contains(v4l::control::Flags::READ_ONLY) || d.flags.contains(v4l::control::Flags::DISABLED) {
                warnings.push(format!("control '{}' is read-only on this camera; left at its value", d.name));
                continue;
            }
            let ctrl = match d.typ {
                CtrlType::Boolean => Control { id: d.id, value: Value::Boolean(v != 0) },
                _ => Control { id: d.id, value: Value::Integer(v) },
            };
            s.dev.set_control(ctrl).map_err(|e| io_err(path, &format!("set control '{}'", d.name), e))?;
            if v != *value {
                warnings.push(format!("control '{}': asked {value}, the camera's range allows {v}", d.name));
            }
        }
        // Read back what the driver kept: that is what is recorded and used.
        for (name, d, value) in &plan {
            let got = s.dev.control(d.id).ok().and_then(|c| int_value(&c.value));
            let Some(got) = got else {
                warnings.push(format!("control '{}' could not be read back", d.name));
                continue;
            };
            recorded.insert(name.to_string(), got);
            if got != *value && all {
                tracing::info!("{}: control '{}' asked {value}, reads back {got}", path.display(), d.name);
            }
            match *name {
                "exposure_absolute" => s.exposure_us = (got.max(0) as u32).saturating_mul(100),
                "exposure" => s.exposure_us = exposure_us,
                "gain" => s.gain = unity.map_or(gain, |u| if u > 0 { got as f32 / u as f32 } else { gain }),
                _ => {}
            }
        }
        if !plan.iter().any(|(n, ..)| n.starts_with("exposure")) {
            s.exposure_us = exposure_us;
        }
        if !plan.iter().any(|(n, ..)| *n == "gain") {
            s.gain = gain;
        }
        Ok(())
    }

    fn gain_unity(&self, d: &CtrlInfo) -> i64 {
        self.opts.gain_unity.unwrap_or(if d.default > 0 { d.default } else { d.minimum.max(1) })
    }

    fn set_exposure(&mut self, exposure_us: u32, gain: f32) -> Result<(), CameraError> {
        self.ensure_session()?;
        let Some(mut s) = self.session.take() else { return Err(self.gone("not configured")) };
        if s.exposure_us == exposure_us && s.gain == gain {
            self.session = Some(s);
            return Ok(());
        }
        let mut warnings = Vec::new();
        let mut recorded = BTreeMap::new();
        let r = self.apply_controls(&mut s, exposure_us, gain, false, &mut warnings, &mut recorded);
        for w in warnings {
            tracing::warn!("{}: {w}", self.opts.path.display());
        }
        s.changed_at = Some(crate::clock::now_mono());
        if let Some(set) = self.settings.as_mut() {
            set.exposure_us = exposure_us;
            set.gain = gain;
        }
        match r {
            Err(CameraError::Gone(why)) => Err(CameraError::Gone(why)),
            other => {
                self.session = Some(s);
                other
            }
        }
    }

    fn gone(&self, why: &str) -> CameraError {
        CameraError::Gone(format!("{}: {why}", self.opts.path.display()))
    }

    /// After the device vanished: open it again and restore the session.
    fn ensure_session(&mut self) -> Result<(), CameraError> {
        if self.session.is_some() {
            return Ok(());
        }
        let Some(settings) = self.settings.clone() else {
            return Err(CameraError::Unsupported("the camera was not configured".into()));
        };
        let dev = open_device(&self.opts.path)?;
        let (session, applied) = self.start_session(dev, &settings, self.next_base)?;
        tracing::info!("{}: camera back ({}, {})", self.opts.path.display(), applied.format, applied.driver);
        self.session = Some(session);
        self.counters.reopened += 1;
        Ok(())
    }

    fn frame_after(&mut self, after: MonoNs, timeout: Duration) -> Result<Frame, CameraError> {
        self.ensure_session()?;
        let give_up = Instant::now() + timeout;
        loop {
            let left = give_up.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(CameraError::Timeout { waited_ms: timeout.as_millis() as u64 });
            }
            let Some(s) = self.session.as_mut() else { return Err(self.gone("not configured")) };
            let Some(st) = s.stream.as_mut() else { return Err(self.gone("not streaming")) };
            st.stream.set_timeout(left.max(Duration::from_millis(1)));
            let (data, meta) = match CaptureStream::next(&mut st.stream) {
                Ok((d, m)) => (d, *m),
                Err(e) if e.kind() == io::ErrorKind::TimedOut => continue,
                Err(e) if is_gone(&e) => {
                    self.next_base = s.last_sequence + 1;
                    self.session = None;
                    return Err(self.gone(&format!("it stopped streaming ({e})")));
                }
                Err(e) => {
                    // A streaming error (EIO after a fatal driver error):
                    // restart the stream once, with the same settings.
                    tracing::warn!("{}: stream error ({e}); restarting the stream", self.opts.path.display());
                    self.next_base = s.last_sequence + 1;
                    self.session = None;
                    self.ensure_session()?;
                    continue;
                }
            };
            let sequence = s.sequence_base + meta.sequence as u64;
            s.last_sequence = sequence;
            let ts = crate::clock::from_timeval(meta.timestamp.sec as i64, meta.timestamp.usec as i64);
            let (start, end) = exposure_window(meta.flags, ts, s.exposure_us, s.interval);
            let error = meta.flags.contains(BufFlags::ERROR);
            let samples = if error {
                None
            } else {
                match s.format.decode(data, meta.bytesused as usize, s.width, s.height, s.stride) {
                    Ok(v) => Some(v),
                    Err(why) => {
                        tracing::debug!("{}: frame {sequence} dropped: {why}", self.opts.path.display());
                        self.counters.dropped_short += 1;
                        continue;
                    }
                }
            };
            let fmeta = FrameMeta {
                sequence,
                exposure_start: start,
                exposure_end: end,
                exposure_us: s.exposure_us,
                gain: s.gain,
                flags: FrameFlags { error },
            };
            if let Some(t) = s.changed_at {
                if start < t {
                    // Exposed with the old settings: not part of the
                    // settle window, which counts frames after the change.
                    self.counters.dropped_early += 1;
                    continue;
                }
                s.changed_at = None;
                self.filter.control_changed(Some(sequence));
            }
            match self.filter.judge(&fmeta, after) {
                Verdict::Accept => {}
                _ => continue,
            }
            self.counters.delivered += 1;
            return Ok(Frame {
                width: s.width,
                height: s.height,
                layout: s.format.layout(),
                bit_depth: s.format.bit_depth(),
                data: samples.unwrap_or_default(),
                meta: fmeta,
            });
        }
    }
}

/// What the driver says about one control (the parts used here).
#[derive(Clone, Debug)]
struct CtrlInfo {
    id: u32,
    name: String,
    typ: CtrlType,
    minimum: i64,
    maximum: i64,
    step: u64,
    default: i64,
    flags: v4l::control::Flags,
}

impl From<&Description> for CtrlInfo {
    fn from(d: &Description) -> Self {
        Self {
            id: d.id,
            name: d.name.clone(),
            typ: d.typ,
            minimum: d.minimum,
            maximum: d.maximum,
            step: d.step,
            default: d.default,
            flags: d.flags,
        }
    }
}

fn int_value(v: &Value) -> Option<i64> {
    match v {
        Value::Integer(i) => Some(*i),
        Value::Boolean(b) => Some(*b as i64),
        _ => None,
    }
}

/// When a frame's exposure began and ended, from its buffer timestamp.
/// With a start-of-exposure timestamp that is exact; with end-of-frame
/// (the default) the start is placed a whole frame interval or exposure,
/// whichever is longer, before it: too early rather than too late, so a
/// frame is never credited to an LED that was not yet lit.
pub fn exposure_window(flags: BufFlags, ts: MonoNs, exposure_us: u32, interval: Duration) -> (MonoNs, MonoNs) {
    let exposure = exposure_us as u64 * 1_000;
    if flags.contains(BufFlags::TSTAMP_SRC_SOE) {
        (ts, MonoNs(ts.0 + exposure))
    } else {
        let back = exposure.max(interval.as_nanos() as u64);
        (MonoNs(ts.0.saturating_sub(back)), ts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn end_of_frame_stamps_start_conservatively_early() {
        let ts = MonoNs(1_000_000_000);
        let eof = BufFlags::TIMESTAMP_MONOTONIC;
        let (s, e) = exposure_window(eof, ts, 5_000, Duration::from_millis(33));
        assert_eq!(e, ts);
        assert_eq!(s, MonoNs(1_000_000_000 - 33_000_000));
        let (s, _) = exposure_window(eof, ts, 50_000, Duration::from_millis(33));
        assert_eq!(s, MonoNs(1_000_000_000 - 50_000_000));
        let (s, e) = exposure_window(eof | BufFlags::TSTAMP_SRC_SOE, ts, 5_000, Duration::from_millis(33));
        assert_eq!((s, e), (ts, MonoNs(1_005_000_000)));
    }

    #[test]
    fn missing_device_is_reported_as_gone_with_its_path() {
        let e = V4l2Camera::open(V4l2Options::new("/dev/reflectometer-no-such-camera")).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, CameraError::Gone(_)), "{msg}");
        assert!(msg.contains("/dev/reflectometer-no-such-camera") && msg.contains("plugged in"), "{msg}");
    }
}
