//! Progress for people and programs: a progress bar on a terminal, plain log
//! lines when headless, and JSON lines with `--json`.

use std::io::Write;
use std::time::Instant;

use fit::FitStage;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

/// One progress event (also the daemon's wire format, one JSON per line).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    Stage {
        stage: String,
        detail: String,
    },
    Frames {
        done: u64,
        total: u64,
        rate_hz: f64,
        eta_s: f64,
    },
    /// The fit's stage after the last frame and its counts.
    Fit(fit::progress::Snapshot),
    /// The serial link's counters so far (about once a second while
    /// capturing; the web page shows them).
    Link(assess::report::LinkReport),
    Warning {
        message: String,
    },
    Done {
        summary: serde_json::Value,
    },
    Error {
        message: String,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Terminal,
    Plain,
    Json,
    Silent,
}

pub struct Reporter {
    mode: Mode,
    bar: Option<ProgressBar>,
    /// The fit's bar and the stage it shows.
    fit_bar: Option<(ProgressBar, FitStage, Option<FitStage>)>,
    started: Instant,
    last_plain: Instant,
    forward: Option<Sink<Event>>,
    /// Shown each frame as it is stored (the web page's camera view).
    frames: Option<Sink<frame::Frame>>,
}

/// Where a reporter also sends what it is given.
type Sink<T> = Box<dyn FnMut(&T) + Send>;

impl std::fmt::Debug for Reporter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reporter").field("mode", &self.mode).finish()
    }
}

impl Reporter {
    pub fn new(mode: Mode) -> Self {
        Self {
            mode,
            bar: None,
            fit_bar: None,
            started: Instant::now(),
            last_plain: Instant::now(),
            forward: None,
            frames: None,
        }
    }

    /// Choose the mode for this process: JSON if asked, a bar on a
    /// terminal, plain lines otherwise.
    pub fn auto(json: bool) -> Self {
        use std::io::IsTerminal;
        Self::new(if json {
            Mode::Json
        } else if std::io::stderr().is_terminal() {
            Mode::Terminal
        } else {
            Mode::Plain
        })
    }

    /// Also send every event to `f` (the daemon streams them to its client).
    pub fn forward_to(mut self, f: impl FnMut(&Event) + Send + 'static) -> Self {
        self.forward = Some(Box::new(f));
        self
    }

    /// Also show every stored frame to `f`.
    pub fn frames_to(mut self, f: impl FnMut(&frame::Frame) + Send + 'static) -> Self {
        self.frames = Some(Box::new(f));
        self
    }

    /// A frame the capture stored.
    pub fn frame(&mut self, f: &frame::Frame) {
        if let Some(show) = self.frames.as_mut() {
            show(f);
        }
    }

    pub fn emit(&mut self, e: Event) {
        if matches!(e, Event::Done { .. } | Event::Error { .. }) {
            self.end_fit();
        }
        if let Some(f) = self.forward.as_mut() {
            f(&e);
        }
        match self.mode {
            Mode::Silent => {}
            Mode::Json => {
                let mut out = std::io::stdout().lock();
                let _ = serde_json::to_writer(&mut out, &e);
                let _ = out.write_all(b"\n");
                let _ = out.flush();
            }
            Mode::Plain => match &e {
                Event::Frames { done, total, rate_hz, eta_s } => {
                    if self.last_plain.elapsed().as_secs_f64() >= 5.0 || done == total {
                        self.last_plain = Instant::now();
                        tracing::info!("frames {done}/{total} ({rate_hz:.1}/s, about {eta_s:.0} s left)");
                    }
                }
                Event::Fit(f) => {
                    if self.last_plain.elapsed().as_secs_f64() >= 5.0 || f.done == f.total {
                        self.last_plain = Instant::now();
                        tracing::info!("{}", describe_fit(f));
                    }
                }
                Event::Link(_) => {}
                Event::Stage { stage, detail } => tracing::info!("{stage}: {detail}"),
                Event::Warning { message } => tracing::warn!("{message}"),
                Event::Done { .. } => tracing::info!("done in {:.1} s", self.started.elapsed().as_secs_f64()),
                Event::Error { message } => tracing::error!("{message}"),
            },
            Mode::Terminal => match &e {
                Event::Frames { done, total, .. } => {
                    let bar = self.bar.get_or_insert_with(|| {
                        let b = ProgressBar::new(*total);
                        b.set_style(
                            ProgressStyle::with_template(
                                "{spinner} {msg} [{bar:40}] {pos}/{len} frames {per_sec} ETA {eta}",
                            )
                            .unwrap_or_else(|_| ProgressStyle::default_bar())
                            .progress_chars("=> "),
                        );
                        b.set_message("capturing");
                        b
                    });
                    bar.set_length(*total);
                    bar.set_position(*done);
                    if done >= total {
                        bar.finish_and_clear();
                        self.bar = None;
                    }
                }
                Event::Fit(f) => {
                    let same = self.fit_bar.as_ref().is_some_and(|(_, s, w)| *s == f.stage && *w == f.within);
                    if !same {
                        self.end_fit();
                        let b = ProgressBar::new(f.total);
                        b.set_style(
                            ProgressStyle::with_template("{spinner} fit: {msg} [{bar:30}] {pos}/{len} ETA {eta}")
                                .unwrap_or_else(|_| ProgressStyle::default_bar())
                                .progress_chars("=> "),
                        );
                        b.set_message(fit_label(f));
                        self.fit_bar = Some((b, f.stage, f.within));
                    }
                    if let Some((b, ..)) = &self.fit_bar {
                        b.set_length(f.total);
                        b.set_position(f.done);
                    }
                }
                Event::Stage { stage, detail } => {
                    if let Some(b) = self.bar.as_ref().or(self.fit_bar.as_ref().map(|f| &f.0)) {
                        b.println(format!("{stage}: {detail}"));
                    } else {
                        eprintln!("{stage}: {detail}");
                    }
                }
                Event::Link(_) => {}
                Event::Warning { message } => eprintln!("warning: {message}"),
                Event::Done { .. } => eprintln!("done in {:.1} s", self.started.elapsed().as_secs_f64()),
                Event::Error { message } => eprintln!("error: {message}"),
            },
        }
    }

    /// The fit is over: clear its bar.
    pub fn end_fit(&mut self) {
        if let Some((b, ..)) = self.fit_bar.take() {
            b.finish_and_clear();
        }
    }

    pub fn stage(&mut self, stage: &str, detail: impl Into<String>) {
        self.emit(Event::Stage { stage: stage.into(), detail: detail.into() });
    }

    pub fn warn(&mut self, message: impl Into<String>) {
        self.emit(Event::Warning { message: message.into() });
    }
}

/// The stage a fit is in: `model choice (pooled NDFs)`.
fn fit_label(f: &fit::progress::Snapshot) -> String {
    match f.within {
        Some(w) => format!("{} ({})", f.stage.describe(), w.describe()),
        None => f.stage.describe().to_string(),
    }
}

/// One line for a fit's progress: `fit: synthesis 1200/9216 (about 8 s left)`.
pub fn describe_fit(f: &fit::progress::Snapshot) -> String {
    let what = fit_label(f);
    let left = f.eta_s.map(|s| format!(", about {s:.0} s left")).unwrap_or_default();
    format!("fit: {what} {}/{} ({:.0} s in{left})", f.done, f.total, f.elapsed_s)
}

impl assess::Progress for Reporter {
    fn stage(&mut self, stage: &str, detail: String) {
        Reporter::stage(self, stage, detail);
    }
}
