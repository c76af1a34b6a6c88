//! `refl daemon --http ADDR`: the rig PC's web page.
//!
//! One page (`web/index.html`, served from the binary) shows what the
//! daemon is doing, live: the job's state, progress and ETA, the latest
//! frame as the camera took it, the serial link's counters and the
//! calibration's age; when a capture ends, its renders, its `refl eval`
//! table and a three.js viewer of the exported glTF. Starting and
//! cancelling a capture need the token the daemon writes at start
//! (`http-token` beside its socket, mode 0640: owner and group only).
//!
//! Routes (JSON unless said otherwise):
//!
//! ```text
//! GET  /                     the page
//! GET  /api/state            the board (below)
//! GET  /api/events           server-sent events: `state`, the board, on each change (at most 5 a second)
//! GET  /api/frame.png        the latest frame, downscaled and brightened, clipped pixels red (404 before the first)
//! GET  /api/rig              the rig file's name and kind, the calibration's id and age
//! GET  /api/samples          the simulated rig's built-in samples and the quality presets
//! POST /api/capture          {"sample": NAME, "quality": PRESET, "overrides": {...}}, with `Authorization: Bearer TOKEN`
//! POST /api/cancel           with the token
//! GET  /result/renders/NAME  a render of the last capture (PNG)
//! GET  /result/gltf/NAME     the last capture's material as glTF, its textures and buffer
//! GET  /vendor/MODULE/PATH   a file of an npm package (three) from the web modules directory
//! ```
//!
//! Nothing is fetched from elsewhere at run time: three.js comes from
//! `web/node_modules` (npm, `web/package.json`), which the daemon finds
//! beside its executable's source tree, in `/usr/share/reflectometer/web`,
//! or where `--web-modules` says. Without it the page works and says the
//! viewer is not installed.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use axum::Router;
use axum::extract::{ConnectInfo, Path as UrlPath, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use crate::capture::CaptureRequest;
use crate::daemon::{Daemon, JobInfo};
use crate::progress::Event;

/// Where the page listens unless told otherwise: loopback only.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8470";
/// The token's file, beside the daemon's socket.
pub const TOKEN_FILE: &str = "http-token";
/// Lines of the job's log the page keeps.
const LOG_LINES: usize = 40;
/// The camera view's longest side, pixels.
const PREVIEW_PX: u32 = 320;
/// Frames are shown at most this often.
const PREVIEW_EVERY: Duration = Duration::from_millis(250);
/// Board updates are sent at most this often to each page.
const PUSH_EVERY: Duration = Duration::from_millis(200);

/// What the page shows: the daemon's job, its progress and the last
/// result. Sent whole at every change (it is small).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Board {
    /// `idle`, `capturing`, `fitting` or `evaluating`.
    pub state: &'static str,
    pub job: Option<JobInfo>,
    /// The capture's latest frame count (a `frames` event).
    pub frames: Option<Event>,
    /// The fit's latest stage and counts (a `fit` event).
    pub fit: Option<Event>,
    pub link: Option<assess::report::LinkReport>,
    /// Bumped at each new camera view (the page reloads the image).
    pub frame_seq: u64,
    /// How much the camera view is brightened ([`preview_png`]).
    pub frame_gain: f32,
    pub log: VecDeque<LogLine>,
    pub result: Option<JobResult>,
}

#[derive(Clone, Debug, Serialize)]
pub struct LogLine {
    /// Seconds since the job started.
    pub t_s: f64,
    /// `stage`, `warning` or `error`.
    pub kind: &'static str,
    pub text: String,
}

/// How the last job ended and what it left.
#[derive(Clone, Debug, Default, Serialize)]
pub struct JobResult {
    pub sample: Option<String>,
    pub dir: Option<PathBuf>,
    /// The exit code `capture` would have given.
    pub exit: i32,
    pub message: Option<String>,
    /// Render file names, under `/result/renders/`.
    pub renders: Vec<String>,
    /// The glTF's file name under `/result/gltf/`, once exported.
    pub gltf: Option<String>,
    /// `refl eval`'s figures, once computed.
    pub eval: Option<serde_json::Value>,
    /// Why the result's glTF or evaluation is missing.
    pub problems: Vec<String>,
}

/// The live board and the latest camera view, shared by the daemon's job
/// and the page's connections.
pub struct Live {
    board: Mutex<Board>,
    started: Mutex<Instant>,
    changed: watch::Sender<u64>,
    /// The latest camera view's PNG (cheap to clone for each request).
    preview: Mutex<Option<axum::body::Bytes>>,
    preview_at: Mutex<Option<Instant>>,
    /// Where a finished capture's glTF is written (the runtime directory's
    /// `web/`).
    export_dir: PathBuf,
}

impl std::fmt::Debug for Live {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Live").field("export_dir", &self.export_dir).finish()
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Live {
    pub fn new(export_dir: PathBuf) -> Self {
        Self {
            board: Mutex::new(Board { state: "idle", ..Board::default() }),
            started: Mutex::new(Instant::now()),
            changed: watch::channel(0).0,
            preview: Mutex::new(None),
            preview_at: Mutex::new(None),
            export_dir,
        }
    }

    pub fn board(&self) -> Board {
        lock(&self.board).clone()
    }

    fn update(&self, f: impl FnOnce(&mut Board)) {
        f(&mut lock(&self.board));
        self.changed.send_modify(|v| *v += 1);
    }

    /// A job started: a fresh board.
    pub fn started(&self, info: &JobInfo) {
        *lock(&self.started) = Instant::now();
        *lock(&self.preview) = None;
        self.update(|b| *b = Board { state: "capturing", job: Some(info.clone()), ..Board::default() });
    }

    /// One of the job's progress events.
    pub fn record(&self, e: &Event) {
        let t_s = lock(&self.started).elapsed().as_secs_f64();
        self.update(|b| match e {
            Event::Frames { .. } => b.frames = Some(e.clone()),
            Event::Fit(_) => {
                b.state = "fitting";
                b.fit = Some(e.clone());
            }
            Event::Link(l) => b.link = Some(l.clone()),
            Event::Stage { stage, detail } => push_log(b, t_s, "stage", format!("{stage}: {detail}")),
            Event::Warning { message } => push_log(b, t_s, "warning", message.clone()),
            Event::Error { message } => push_log(b, t_s, "error", message.clone()),
            Event::Done { .. } => push_log(b, t_s, "stage", "done".into()),
        });
    }

    /// A frame the capture stored: the new camera view, at most every
    /// [`PREVIEW_EVERY`].
    pub fn frame(&self, f: &frame::Frame) {
        {
            let mut at = lock(&self.preview_at);
            if at.is_some_and(|t| t.elapsed() < PREVIEW_EVERY) {
                return;
            }
            *at = Some(Instant::now());
        }
        match preview_png(f, PREVIEW_PX) {
            Ok((png, gain)) => {
                *lock(&self.preview) = Some(png.into());
                self.update(|b| {
                    b.frame_seq += 1;
                    b.frame_gain = gain;
                });
            }
            Err(e) => tracing::warn!(error = %e, "cannot encode the camera view"),
        }
    }

    /// The job ended with `exit`; a finished capture's glTF and evaluation
    /// are made next (`evaluate`), its renders listed now.
    pub fn ended(&self, info: &JobInfo, dir: Option<&Path>, exit: i32, message: Option<String>) {
        let renders = dir.map(|d| file_names(&d.join("renders"), "png")).unwrap_or_default();
        let result = JobResult {
            sample: info.sample.clone(),
            dir: dir.map(Path::to_path_buf),
            exit,
            message,
            renders,
            ..JobResult::default()
        };
        let evaluating = exit == 0 && dir.is_some();
        self.update(|b| {
            b.state = if evaluating { "evaluating" } else { "idle" };
            b.job = None;
            b.result = Some(result);
        });
    }

    /// Export the finished capture in `dir` as glTF and evaluate it (as
    /// `refl eval` would, without its hold-out refit), for the page. Runs
    /// on a blocking thread; the board says `evaluating` meanwhile.
    pub fn evaluate(&self, dir: &Path) {
        let mut problems = Vec::new();
        let gltf = match export_gltf(dir, &self.export_dir) {
            Ok(name) => Some(name),
            Err(e) => {
                problems.push(format!("no glTF: {e:#}"));
                None
            }
        };
        let mut quiet = crate::progress::Reporter::new(crate::progress::Mode::Silent);
        let opts = assess::eval::EvalOptions { render_px: 64, holdout: false, ..Default::default() };
        let eval = match assess::eval::evaluate(dir, &opts, &mut quiet) {
            Ok(ev) => serde_json::to_value(&ev).ok(),
            Err(e) => {
                problems.push(format!("no evaluation: {e:#}"));
                None
            }
        };
        self.update(|b| {
            // A new job may have started meanwhile; its board stays.
            if b.state == "evaluating" {
                b.state = "idle";
            }
            if let Some(r) = b.result.as_mut().filter(|r| r.dir.as_deref() == Some(dir)) {
                r.gltf = gltf;
                r.eval = eval;
                r.problems = problems;
            }
        });
    }
}

fn push_log(b: &mut Board, t_s: f64, kind: &'static str, text: String) {
    if b.log.len() == LOG_LINES {
        b.log.pop_front();
    }
    b.log.push_back(LogLine { t_s, kind, text });
}

/// Names of the files in `dir` ending `.ext`, sorted.
fn file_names(dir: &Path, ext: &str) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter_map(|e| e.file_name().into_string().ok())
                .filter(|n| n.ends_with(&format!(".{ext}")) && safe_name(n))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// The capture's material as `material.gltf` in a fresh `out`.
fn export_gltf(dir: &Path, out: &Path) -> Result<String> {
    let mdir = dir.join("material");
    let m = material::read(&mdir).with_context(|| format!("reading {}", mdir.display()))?;
    if out.exists() {
        std::fs::remove_dir_all(out).with_context(|| format!("cannot clear {}", out.display()))?;
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    assess::gltf::export(&m, &out.join("material.gltf"))?;
    Ok("material.gltf".into())
}

/// Most a dim frame is brightened for the page.
const PREVIEW_MAX_GAIN: f32 = 64.0;

/// The frame downscaled (box filter) to at most `max_px` a side: linear
/// counts over the sensor's range, brightened so that the 99.5th
/// percentile of the unclipped blocks' luminance shows at 0.8 (never
/// darkened, at most [`PREVIEW_MAX_GAIN`]), sRGB-encoded; a block holding a
/// clipped pixel is red. Returns the PNG and the gain.
pub fn preview_png(f: &frame::Frame, max_px: u32) -> Result<(Vec<u8>, f32)> {
    use image::ImageEncoder;
    let rgb = f.to_rgb();
    let k = rgb.width.max(rgb.height).div_ceil(max_px.max(1)).max(1);
    let (w, h) = (rgb.width / k, rgb.height / k);
    anyhow::ensure!(w > 0 && h > 0, "a {}x{} frame is too small to show", rgb.width, rgb.height);
    let n = (k * k) as f32 * f.max_value() as f32;
    let mut blocks = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut clipped) = ([0f32; 3], false);
            for dy in 0..k {
                for dx in 0..k {
                    let i = ((y * k + dy) * rgb.width + x * k + dx) as usize;
                    s[0] += rgb.r[i];
                    s[1] += rgb.g[i];
                    s[2] += rgb.b[i];
                    clipped |= rgb.clipped[i];
                }
            }
            blocks.push((s.map(|v| v / n), clipped));
        }
    }
    // Clipped blocks show red whatever the gain: they do not set it.
    let mut lum: Vec<f32> = blocks
        .iter()
        .filter(|(_, clipped)| !clipped)
        .map(|(c, _)| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
        .collect();
    let p = if lum.is_empty() {
        0.0
    } else {
        let at = ((lum.len() as f32 * 0.995) as usize).min(lum.len() - 1);
        *lum.select_nth_unstable_by(at, f32::total_cmp).1
    };
    let gain = if p > 0.0 { (0.8 / p).clamp(1.0, PREVIEW_MAX_GAIN) } else { 1.0 };
    let out: Vec<u8> = blocks
        .iter()
        .flat_map(|(c, clipped)| if *clipped { [255, 0, 0] } else { c.map(|v| render::output::srgb(v * gain)) })
        .collect();
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png).write_image(&out, w, h, image::ExtendedColorType::Rgb8)?;
    Ok((png, gain))
}

/// A file name the page may ask for: letters, digits, `.`, `_`, `-`, not
/// starting with a dot.
fn safe_name(n: &str) -> bool {
    !n.is_empty()
        && !n.starts_with('.')
        && n.len() <= 200
        && n.bytes().all(|c| c.is_ascii_alphanumeric() || matches!(c, b'.' | b'_' | b'-'))
}

/// A fresh token: 128 bits from the kernel's random source, in hex.
fn new_token() -> Result<String> {
    use std::io::Read;
    let mut b = [0u8; 16];
    std::fs::File::open("/dev/urandom").and_then(|mut f| f.read_exact(&mut b)).context("cannot read /dev/urandom")?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// Write the token to `path`, readable by owner and group only.
fn write_token(path: &Path, token: &str) -> Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let _ = std::fs::remove_file(path);
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o640)
        .open(path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    writeln!(f, "{token}").with_context(|| format!("cannot write {}", path.display()))
}

/// Equal strings, compared in time independent of where they differ.
fn same_secret(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

/// Where npm packages for the page live: `--web-modules`, else the source
/// tree's `web/node_modules` (beside `target/`), else the system's.
pub fn find_modules(given: Option<PathBuf>) -> Option<PathBuf> {
    if given.is_some() {
        return given;
    }
    let mut candidates = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        // target/{debug,release}/refl -> the tree's web/node_modules.
        if let Some(tree) = exe.parent().and_then(Path::parent).and_then(Path::parent) {
            candidates.push(tree.join("web/node_modules"));
        }
    }
    candidates.push(PathBuf::from("/usr/share/reflectometer/web/node_modules"));
    candidates.into_iter().find(|d| d.join("three/package.json").is_file())
}

#[derive(Clone)]
struct App {
    daemon: Arc<Daemon>,
    live: Arc<Live>,
    token: Arc<String>,
    modules: Option<PathBuf>,
    stop: watch::Receiver<bool>,
}

/// Serve the page on `listener` until `stop` turns true.
pub async fn serve(
    listener: tokio::net::TcpListener,
    daemon: Arc<Daemon>,
    live: Arc<Live>,
    token_dir: &Path,
    modules: Option<PathBuf>,
    stop: watch::Receiver<bool>,
) -> Result<()> {
    let token = new_token()?;
    let token_path = token_dir.join(TOKEN_FILE);
    write_token(&token_path, &token)?;
    let local = listener.local_addr()?;
    tracing::info!("web page on http://{local}/ ; token {token} (also in {})", token_path.display());
    match &modules {
        Some(m) if m.join("three/package.json").is_file() => {
            tracing::info!("the page's 3D viewer uses three.js from {}", m.display())
        }
        Some(m) => tracing::warn!(
            "{} holds no three.js (run `npm ci` there with web/package.json): the page works without its 3D viewer",
            m.display()
        ),
        None => tracing::warn!(
            "three.js not found (run `npm ci --prefix web`, or pass --web-modules): the page works without its 3D viewer"
        ),
    }
    let app = App { daemon, live, token: Arc::new(token), modules, stop: stop.clone() };
    let router = Router::new()
        .route("/", get(|| async { with_type("text/html; charset=utf-8", INDEX_HTML) }))
        .route("/app.js", get(|| async { with_type(JS, APP_JS) }))
        .route("/viewer.js", get(|| async { with_type(JS, VIEWER_JS) }))
        .route("/api/state", get(state))
        .route("/api/events", get(events))
        .route("/api/frame.png", get(frame_png))
        .route("/api/rig", get(rig))
        .route("/api/samples", get(samples))
        .route("/api/capture", post(start))
        .route("/api/cancel", post(cancel))
        .route("/result/{kind}/{name}", get(result_file))
        .route("/vendor/{*path}", get(vendor))
        .with_state(app);
    let mut stop2 = stop;
    let r = axum::serve(listener, router.into_make_service_with_connect_info::<SocketAddr>())
        .with_graceful_shutdown(async move {
            let _ = stop2.wait_for(|s| *s).await;
        })
        .await;
    let _ = std::fs::remove_file(&token_path);
    r.context("the web page's server failed")
}

const INDEX_HTML: &str = include_str!("../web/index.html");
const APP_JS: &str = include_str!("../web/app.js");
const VIEWER_JS: &str = include_str!("../web/viewer.js");
const JS: &str = "text/javascript; charset=utf-8";

fn with_type(ct: &'static str, body: impl IntoResponse) -> Response {
    let mut r = body.into_response();
    r.headers_mut().insert(header::CONTENT_TYPE, HeaderValue::from_static(ct));
    r.headers_mut().insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

async fn state(State(app): State<App>) -> Response {
    axum::Json(app.live.board()).into_response()
}

async fn events(State(app): State<App>) -> Response {
    let rx = app.live.changed.subscribe();
    let stream = futures_util::stream::unfold((rx, app, true), |(mut rx, app, first)| async move {
        if !first {
            let mut stop = app.stop.clone();
            tokio::select! {
                c = rx.changed() => c.ok()?,
                _ = stop.wait_for(|s| *s) => return None,
            }
            tokio::time::sleep(PUSH_EVERY).await;
            rx.borrow_and_update();
        }
        let data = serde_json::to_string(&app.live.board()).ok()?;
        Some((Ok::<_, std::convert::Infallible>(SseEvent::default().event("state").data(data)), (rx, app, false)))
    });
    Sse::new(stream).keep_alive(KeepAlive::default()).into_response()
}

async fn frame_png(State(app): State<App>) -> Response {
    match lock(&app.live.preview).clone() {
        Some(png) => with_type("image/png", png),
        None => (StatusCode::NOT_FOUND, "no frame yet").into_response(),
    }
}

/// The rig and its calibration, as a capture would find them.
#[derive(Serialize)]
struct RigView {
    name: String,
    kind: String,
    source: String,
    calibration: Option<CalibrationView>,
    problem: Option<String>,
}

#[derive(Serialize)]
struct CalibrationView {
    id: String,
    path: String,
    age_days: Option<i64>,
    geometric: bool,
}

async fn rig() -> Response {
    let r = tokio::task::spawn_blocking(|| rig_view(None)).await;
    match r {
        Ok(Ok(v)) => axum::Json(v).into_response(),
        Ok(Err(e)) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}")).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

fn rig_view(rig_file: Option<&Path>) -> Result<RigView> {
    let (rf, source) = config::RigFile::load(rig_file)?;
    let kind = format!("{:?}", rf.kind).to_lowercase();
    let (calibration, problem) =
        match crate::paths::calibrations(None, &rf.calibration_key()).and_then(|s| Ok(s.newest()?)) {
            Ok(Some((path, c))) => {
                let now = crate::paths::stamp_days(&crate::paths::utc_stamp());
                let age_days = now.zip(crate::paths::stamp_days(&c.id)).map(|(n, t)| n - t);
                let geometric = c.camera.is_some() && c.lights.is_some();
                (Some(CalibrationView { id: c.id, path: path.display().to_string(), age_days, geometric }), None)
            }
            Ok(None) => (None, Some("no calibration yet".to_string())),
            Err(e) => (None, Some(format!("{e:#}"))),
        };
    Ok(RigView { name: rf.name, kind, source, calibration, problem })
}

async fn samples() -> Response {
    let builtin: Vec<_> =
        sim::materials::BUILTIN.iter().map(|(n, d)| serde_json::json!({ "name": n, "about": d })).collect();
    axum::Json(serde_json::json!({ "builtin": builtin, "qualities": config::presets::PRESETS })).into_response()
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StartRequest {
    sample: String,
    #[serde(default)]
    quality: Option<String>,
    /// The preset's settings changed, as `capture`'s options do (`steps`,
    /// `grid`, `camera_px`, ...).
    #[serde(default)]
    overrides: config::presets::Overrides,
}

/// Check the request's token; a refusal is logged with where it came from.
fn refused(app: &App, headers: &HeaderMap, from: SocketAddr, what: &str) -> Option<Response> {
    let given = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::trim);
    match given {
        Some(t) if same_secret(t.as_bytes(), app.token.as_bytes()) => None,
        Some(_) => {
            tracing::warn!(%from, "web page: {what} refused: wrong token");
            Some((StatusCode::FORBIDDEN, "wrong token").into_response())
        }
        None => {
            tracing::warn!(%from, "web page: {what} refused: no token");
            Some(
                (StatusCode::UNAUTHORIZED, "this needs the daemon's token (Authorization: Bearer TOKEN)")
                    .into_response(),
            )
        }
    }
}

async fn start(
    State(app): State<App>,
    ConnectInfo(from): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: axum::body::Bytes,
) -> Response {
    if let Some(r) = refused(&app, &headers, from, "capture") {
        return r;
    }
    let req: StartRequest = match serde_json::from_slice(&body) {
        Ok(r) => r,
        Err(e) => return (StatusCode::BAD_REQUEST, format!("bad request: {e}")).into_response(),
    };
    // The sample names the capture's directory: a plain name only.
    if !safe_name(&req.sample) || req.sample.contains('.') {
        return (StatusCode::BAD_REQUEST, "a sample name is letters, digits, '_' and '-'").into_response();
    }
    let quality = req.quality.unwrap_or_else(|| "balanced".into());
    if config::presets::preset(&quality).is_none() {
        let known = config::presets::PRESETS.join(", ");
        return (StatusCode::BAD_REQUEST, format!("unknown quality '{quality}': use one of {known}")).into_response();
    }
    let out = match crate::paths::data_dir() {
        Ok(d) => d.join("captures").join(format!("{}-{}", req.sample, crate::paths::utc_stamp())),
        Err(e) => return (StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}")).into_response(),
    };
    let request = CaptureRequest {
        sample: Some(req.sample.clone()),
        out: Some(out.clone()),
        quality: Some(quality),
        overrides: req.overrides,
        ..CaptureRequest::default()
    };
    tracing::info!(%from, sample = %req.sample, "web page: capture into {}", out.display());
    match crate::daemon::start_job(&app.daemon, request) {
        // The job runs on; the page follows it on the board.
        Ok(_job) => (StatusCode::ACCEPTED, axum::Json(serde_json::json!({ "out": out }))).into_response(),
        Err(busy) => (StatusCode::CONFLICT, busy).into_response(),
    }
}

async fn cancel(State(app): State<App>, ConnectInfo(from): ConnectInfo<SocketAddr>, headers: HeaderMap) -> Response {
    if let Some(r) = refused(&app, &headers, from, "cancel") {
        return r;
    }
    let cancelled = crate::daemon::cancel_job(&app.daemon);
    tracing::info!(%from, cancelled, "web page: cancel");
    axum::Json(serde_json::json!({ "cancelled": cancelled })).into_response()
}

fn content_type(name: &str) -> &'static str {
    match name.rsplit('.').next().unwrap_or("") {
        "js" | "mjs" => JS,
        "json" => "application/json",
        "gltf" => "model/gltf+json",
        "png" => "image/png",
        "html" => "text/html; charset=utf-8",
        "css" => "text/css",
        _ => "application/octet-stream",
    }
}

async fn send_file(path: PathBuf) -> Response {
    let ct = content_type(&path.to_string_lossy());
    match tokio::fs::read(&path).await {
        Ok(b) => with_type(ct, b),
        Err(_) => (StatusCode::NOT_FOUND, "no such file").into_response(),
    }
}

async fn result_file(State(app): State<App>, UrlPath((kind, name)): UrlPath<(String, String)>) -> Response {
    if !safe_name(&name) {
        return (StatusCode::BAD_REQUEST, "bad file name").into_response();
    }
    let dir = match kind.as_str() {
        "renders" => match app.live.board().result.and_then(|r| r.dir) {
            Some(d) => d.join("renders"),
            None => return (StatusCode::NOT_FOUND, "no capture has finished").into_response(),
        },
        "gltf" => app.live.export_dir.clone(),
        _ => return (StatusCode::NOT_FOUND, "no such result").into_response(),
    };
    send_file(dir.join(name)).await
}

async fn vendor(State(app): State<App>, UrlPath(path): UrlPath<String>) -> Response {
    let Some(root) = &app.modules else {
        return (StatusCode::NOT_FOUND, "three.js is not installed (npm ci --prefix web)").into_response();
    };
    // Only the page's own packages, and no way out of them.
    if !path.starts_with("three/") || !path.split('/').all(safe_name) {
        return (StatusCode::BAD_REQUEST, "bad path").into_response();
    }
    send_file(root.join(path)).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_could_leave_the_directory_are_refused() {
        for bad in ["", "..", ".hidden", "a/b", "a\\b", "../x.png", "x.png\0", "ä.png"] {
            assert!(!safe_name(bad), "{bad:?}");
        }
        for good in ["satin_tabulated.png", "material.gltf", "three.module.js", "x-1.bin"] {
            assert!(safe_name(good), "{good}");
        }
    }

    #[test]
    fn secrets_compare_whole() {
        assert!(same_secret(b"abc", b"abc"));
        assert!(!same_secret(b"abc", b"abd"));
        assert!(!same_secret(b"abc", b"ab"));
        assert!(!same_secret(b"", b"a"));
    }

    #[test]
    fn the_camera_view_is_downscaled_and_shows_clipping() {
        let (w, h) = (64u32, 40u32);
        let mut data = vec![1000u16; (w * h) as usize];
        data[0] = 4095;
        let mut f = frame::Frame {
            width: w,
            height: h,
            layout: frame::Layout::Mono,
            bit_depth: 12,
            data,
            meta: frame::FrameMeta {
                sequence: 0,
                exposure_start: frame::MonoNs(0),
                exposure_end: frame::MonoNs(1),
                exposure_us: 1000,
                gain: 1.0,
                flags: frame::FrameFlags::default(),
            },
        };
        let (png, gain) = preview_png(&f, 16).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        // 64 x 40 by a factor of 4.
        assert_eq!((img.width(), img.height()), (16, 10));
        // The block holding the clipped pixel is red; the others are
        // 1000/4095 of full scale, brightened to 0.8 (their luminance is
        // the 99.5th percentile's), sRGB-encoded, grey.
        assert_eq!(img.get_pixel(0, 0).0, [255, 0, 0]);
        assert!((gain - 0.8 * 4095.0 / 1000.0).abs() < 1e-3, "{gain}");
        let grey = render::output::srgb(0.8);
        assert_eq!(img.get_pixel(5, 5).0, [grey, grey, grey]);
        // A bright frame is never darkened.
        f.data.iter_mut().for_each(|v| *v = 4000);
        assert_eq!(preview_png(&f, 16).unwrap().1, 1.0);
    }
}
