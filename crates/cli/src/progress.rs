//! Progress for people and programs: a progress bar on a terminal, plain log
//! lines when headless, and JSON lines with `--json`.

use std::io::Write;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

/// One progress event (also the daemon's wire format, one JSON per line).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    Stage { stage: String, detail: String },
    Frames { done: u64, total: u64, rate_hz: f64, eta_s: f64 },
    Warning { message: String },
    Done { summary: serde_json::Value },
    Error { message: String },
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
    started: Instant,
    last_plain: Instant,
    forward: Option<Box<dyn FnMut(&Event) + Send>>,
}

impl std::fmt::Debug for Reporter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reporter").field("mode", &self.mode).finish()
    }
}

impl Reporter {
    pub fn new(mode: Mode) -> Self {
        Self { mode, bar: None, started: Instant::now(), last_plain: Instant::now(), forward: None }
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

    pub fn emit(&mut self, e: Event) {
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
                Event::Stage { stage, detail } => {
                    if let Some(b) = &self.bar {
                        b.println(format!("{stage}: {detail}"));
                    } else {
                        eprintln!("{stage}: {detail}");
                    }
                }
                Event::Warning { message } => eprintln!("warning: {message}"),
                Event::Done { .. } => eprintln!("done in {:.1} s", self.started.elapsed().as_secs_f64()),
                Event::Error { message } => eprintln!("error: {message}"),
            },
        }
    }

    pub fn stage(&mut self, stage: &str, detail: impl Into<String>) {
        self.emit(Event::Stage { stage: stage.into(), detail: detail.into() });
    }

    pub fn warn(&mut self, message: impl Into<String>) {
        self.emit(Event::Warning { message: message.into() });
    }
}

impl assess::Progress for Reporter {
    fn stage(&mut self, stage: &str, detail: String) {
        Reporter::stage(self, stage, detail);
    }
}
