//! A fit spread over machines. `refl fit DIR --tile K/N` reads every
//! stored frame but keeps the samples of tile `K`'s points only (the grid's
//! points in `N` consecutive runs), fits those points (stage 2 of
//! `fit::pipeline`) and writes `DIR/tiles/K-of-N.tile` with a done marker
//! `K-of-N.done`. Tiles share the capture's lock (many run at once, on one
//! machine or on many over a shared file system); a capture still taking
//! frames holds it alone and refuses them. `refl fit DIR --merge` then
//! reads the `N` tiles, runs the stages that need every point (synthesis,
//! analytic fits, pooling, the model choice) and writes the material, the
//! same material byte for byte as `refl fit DIR` writes, and removes the
//! tiles.
//!
//! A tile file is this program's own intermediate: a header, then raw
//! little-endian arrays, then a CRC-32 of everything before it. Reading
//! one checks every length against the header and the checksum, so a
//! truncated or damaged tile is refused with what to run again, never
//! fitted.

use std::io::{BufReader, BufWriter, Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use brdf::ndf::{NdfGrid, TableSet};
use fit::partial::PointStats;
use fit::{PointMaps, SampleStore, TileFit};
use half::f16;
use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use crate::progress::{Event, Reporter};

/// The subdirectory of a capture holding its tiles.
pub const TILES_DIR: &str = "tiles";

const MAGIC: &[u8; 8] = b"REFLTILE";
const VERSION: u32 = 2;
/// A header longer than this is not one of ours.
const MAX_HEADER: u32 = 1 << 20;

/// Tile `index` of `count` (0-based, as Slurm's array and Kubernetes'
/// indexed jobs number their tasks).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Tile {
    pub index: u32,
    pub count: u32,
}

impl std::str::FromStr for Tile {
    type Err = String;

    /// `K/N` with `0 <= K < N`.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("'{s}' is not a tile: give K/N, tile K (from 0) of N, e.g. 0/4");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (u32, u32) = (k.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if count == 0 || index >= count {
            return Err(format!("tile {index}/{count} does not exist: K counts from 0 to N-1"));
        }
        Ok(Tile { index, count })
    }
}

impl std::fmt::Display for Tile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Tile {
    /// The grid's points this tile fits, of `n` (consecutive runs of equal
    /// length, to one point).
    pub fn points(&self, n: usize) -> Range<usize> {
        let at = |k: u32| (n as u64 * k as u64 / self.count as u64) as usize;
        at(self.index)..at(self.index + 1)
    }

    fn stem(&self) -> String {
        format!("{}-of-{}", self.index, self.count)
    }

    pub fn file(&self, capture: &Path) -> PathBuf {
        capture.join(TILES_DIR).join(format!("{}.tile", self.stem()))
    }

    pub fn marker(&self, capture: &Path) -> PathBuf {
        capture.join(TILES_DIR).join(format!("{}.done", self.stem()))
    }
}

/// What a tile was made from and what it holds. The `inputs` fingerprint
/// ties it to its capture and settings ([`fingerprint`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileHeader {
    pub version: u32,
    pub tile: Tile,
    pub inputs: String,
    pub points: Range<usize>,
    pub lights: usize,
    pub grid: NdfGrid,
    pub frames: u64,
    pub ingest_s: f64,
    pub points_s: f64,
    pub drift: Option<fit::drift::DriftSummary>,
}

/// What the tiles of one fit must share: the capture's description (but
/// its status, which a fit changes), the frames stored (their manifest
/// entries, checksums included) and the fitting settings.
pub fn fingerprint(
    info: &store::CaptureInfo,
    entries: &[store::ManifestEntry],
    fit: &fit::FitSettings,
) -> Result<String> {
    let mut described = serde_json::to_value(info)?;
    if let Some(o) = described.as_object_mut() {
        o.remove("status");
    }
    let mut h = crc32fast::Hasher::new();
    h.update(&serde_json::to_vec(&described)?);
    h.update(&serde_json::to_vec(entries)?);
    h.update(&serde_json::to_vec(fit)?);
    Ok(format!("{:08x}-{}", h.finalize(), entries.len()))
}

/// How often a tile's progress is reported.
const PROGRESS_EVERY: std::time::Duration = std::time::Duration::from_secs(1);

/// `refl fit DIR --tile K/N`: fit tile `tile`'s points of a stored capture
/// and write its tile file and done marker. Returns the tile file.
pub async fn fit_tile(
    dir: &Path,
    tile: Tile,
    q_override: Option<config::Quality>,
    partial: bool,
    rep: &mut Reporter,
    stop: &watch::Receiver<bool>,
) -> Result<PathBuf> {
    let (lock, s) = crate::output::open_stored(dir, true, q_override, partial, rep)?;
    let inputs_id = fingerprint(&s.info, &s.entries, &s.q.fit)?;
    let ctx = fit::FitContext::new(crate::fitjob::fit_inputs(&s.info));
    let points = tile.points(ctx.n_points());
    if points.is_empty() {
        return Err(crate::usage(anyhow!(
            "tile {tile} holds no point: the capture has {} points, fewer than {} tiles",
            ctx.n_points(),
            tile.count
        )));
    }
    rep.stage("fit", format!("tile {tile}: points {}..{} of {}", points.start, points.end, ctx.n_points()));
    let progress = std::sync::Arc::new(fit::FitProgress::new());
    let ctx = ctx.with_progress(progress.clone());
    let stopped = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (dir2, stopped2, settings, frames) = (dir.to_path_buf(), stopped.clone(), s.q.fit.clone(), s.entries.len());
    let read = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let read2 = read.clone();
    let t = std::time::Instant::now();
    let job = tokio::task::spawn_blocking(move || -> Result<fit::TileFit> {
        let is_stopped = || stopped2.load(std::sync::atomic::Ordering::Relaxed);
        let mut sink = fit::TilePipeline::new(&ctx, settings, points);
        assess::replay::for_each_frame(&dir2, &s.entries, &mut |msg| {
            if is_stopped() {
                return Err(crate::Interrupted.into());
            }
            msg.feed(&mut sink);
            read2.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Ok(())
        })?;
        Ok(sink.finish(&is_stopped)?)
    });
    tokio::pin!(job);
    let mut tick = tokio::time::interval(PROGRESS_EVERY);
    let mut watch_stop = stop.clone();
    let out = loop {
        tokio::select! {
            r = &mut job => break r.map_err(|e| anyhow!("the tile's fit failed: {e}"))??,
            _ = watch_stop.wait_for(|s| *s) => {
                stopped.store(true, std::sync::atomic::Ordering::Relaxed);
                return Err(crate::Interrupted.into());
            }
            _ = tick.tick() => {
                let n = read.load(std::sync::atomic::Ordering::Relaxed);
                if (n as usize) < frames {
                    let rate_hz = n as f64 / t.elapsed().as_secs_f64().max(1e-3);
                    let eta_s = (frames as u64 - n) as f64 / rate_hz.max(1e-3);
                    rep.emit(Event::Frames { done: n, total: frames as u64, rate_hz, eta_s });
                } else if let Some(p) = progress.snapshot() {
                    rep.emit(Event::Fit(p));
                }
            }
        }
    };
    rep.end_fit();
    rep.stage(
        "fit",
        format!(
            "tile {tile}: {} frames read and {} points fitted in {:.1} s",
            out.frames,
            out.maps.len(),
            t.elapsed().as_secs_f64()
        ),
    );
    let header = TileHeader {
        version: VERSION,
        tile,
        inputs: inputs_id,
        points: out.store.points(),
        lights: out.store.n_lights(),
        grid: out.maps.tables.grid(),
        frames: out.frames,
        ingest_s: out.ingest_s,
        points_s: out.points_s,
        drift: out.drift,
    };
    let path = tokio::task::block_in_place(|| write(dir, &header, &out))?;
    drop(lock);
    Ok(path)
}

/// `refl fit DIR --merge`: the stages after the per-point fit on the
/// capture's tiles, then the material and report as `refl fit DIR` writes
/// them; the tiles are removed once the material is written.
pub async fn merge(
    dir: &Path,
    q_override: Option<config::Quality>,
    partial: bool,
    rep: &mut Reporter,
    stop: &watch::Receiver<bool>,
) -> Result<PathBuf> {
    let (lock, s) = crate::output::open_stored(dir, false, q_override, partial, rep)?;
    let inputs_id = fingerprint(&s.info, &s.entries, &s.q.fit)?;
    let inputs = crate::fitjob::fit_inputs(&s.info);
    let t = std::time::Instant::now();
    let (tiles, whole) =
        tokio::task::block_in_place(|| read_all(dir, &inputs_id, inputs.grid.len())).map_err(crate::usage)?;
    rep.stage("fit", format!("{} tiles read in {:.1} s", tiles.len(), t.elapsed().as_secs_f64()));
    let job =
        crate::fitjob::FitJob::start_merged(inputs, s.q.fit.clone(), s.q.stages(&config::Overrides::default()), whole);
    let m = crate::output::finish_stored(dir, s, job, lock, rep, stop).await?;
    if let Err(e) = remove(dir) {
        rep.warn(format!("the material is written, but its tiles stay: {e:#}"));
    }
    Ok(m)
}

/// A writer that keeps the CRC-32 of what went through it.
struct Crc<W> {
    inner: W,
    crc: crc32fast::Hasher,
}

impl<W: Write> Write for Crc<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.crc.update(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// A reader that keeps the CRC-32 of what came through it.
struct CrcRead<R> {
    inner: R,
    crc: crc32fast::Hasher,
}

impl<R: Read> Read for CrcRead<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.crc.update(&buf[..n]);
        Ok(n)
    }
}

fn put<W: Write, T: Copy, const B: usize>(w: &mut W, xs: &[T], bytes: impl Fn(T) -> [u8; B]) -> std::io::Result<()> {
    for chunk in xs.chunks(4096) {
        let buf: Vec<u8> = chunk.iter().flat_map(|&x| bytes(x)).collect();
        w.write_all(&buf)?;
    }
    Ok(())
}

fn take<R: Read, T, const B: usize>(r: &mut R, n: usize, from: impl Fn([u8; B]) -> T) -> std::io::Result<Vec<T>> {
    let mut out = Vec::with_capacity(n);
    let mut buf = vec![0u8; 4096 * B];
    let mut left = n;
    while left > 0 {
        let k = left.min(4096);
        r.read_exact(&mut buf[..k * B])?;
        out.extend(buf[..k * B].chunks_exact(B).map(|c| from(c.try_into().expect("chunks of B bytes"))));
        left -= k;
    }
    Ok(out)
}

fn f32s(xs: &[[f32; 3]]) -> Vec<f32> {
    xs.iter().flatten().copied().collect()
}

fn triples(xs: Vec<f32>) -> Vec<[f32; 3]> {
    xs.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn encode(w: &mut impl Write, header: &TileHeader, t: &TileFit) -> std::io::Result<()> {
    let json = serde_json::to_vec(header).map_err(std::io::Error::other)?;
    w.write_all(MAGIC)?;
    w.write_all(&VERSION.to_le_bytes())?;
    w.write_all(&(json.len() as u32).to_le_bytes())?;
    w.write_all(&json)?;
    // Each light's flags, then each light's reflectances (zero where a
    // flag rules one out): read in this order, a sample store never holds
    // a reflectance its flag rules out.
    let s = &t.store;
    for q in 0..s.n_lights() {
        w.write_all(s.flag_row(q))?;
    }
    for q in 0..s.n_lights() {
        put(w, &s.rho_row(q), |x: [f16; 3]| {
            let [a, b, c] = x.map(|v| v.to_bits().to_le_bytes());
            [a[0], a[1], b[0], b[1], c[0], c[1]]
        })?;
    }
    let m = &t.maps;
    put(w, &f32s(&m.kd), f32::to_le_bytes)?;
    put(w, &f32s(&m.ks), f32::to_le_bytes)?;
    put(w, &m.eta, f32::to_le_bytes)?;
    put(w, &m.flags, u32::to_le_bytes)?;
    let stats: Vec<u32> = m
        .stats
        .iter()
        .flat_map(|s| [s.usable, s.saturated, s.significant, s.iterations, s.noise.to_bits(), s.coverage.to_bits()])
        .collect();
    put(w, &stats, u32::to_le_bytes)?;
    let (values, coverage) = m.tables.raw();
    put(w, values, |v: f16| v.to_bits().to_le_bytes())?;
    put(w, coverage, u64::to_le_bytes)?;
    Ok(())
}

/// Write tile `t`'s file, then its done marker (the header as JSON): a
/// marker always names a whole tile file.
pub fn write(capture: &Path, header: &TileHeader, t: &TileFit) -> Result<PathBuf> {
    let dir = capture.join(TILES_DIR);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = header.tile.file(capture);
    let marker = header.tile.marker(capture);
    // A tile made again replaces the old one: no marker without its file.
    match std::fs::remove_file(&marker) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("removing {}", marker.display()));
        }
        _ => {}
    }
    let tmp = dir.join(format!(".{}.tmp", header.tile.stem()));
    let written = (|| -> std::io::Result<()> {
        let file = std::fs::File::create(&tmp)?;
        let mut w = Crc { inner: BufWriter::new(file), crc: crc32fast::Hasher::new() };
        encode(&mut w, header, t)?;
        let crc = w.crc.clone().finalize();
        let mut inner = w.inner;
        inner.write_all(&crc.to_le_bytes())?;
        inner.into_inner().map_err(|e| e.into_error())?.sync_all()
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(e).with_context(|| format!("writing {}", tmp.display()));
    }
    std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))?;
    let tmp = dir.join(format!(".{}.done.tmp", header.tile.stem()));
    std::fs::write(&tmp, serde_json::to_vec_pretty(header)?).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &marker).with_context(|| format!("writing {}", marker.display()))?;
    Ok(path)
}

fn damaged(path: &Path, why: String) -> anyhow::Error {
    anyhow!("{} is not a whole tile ({why}); make it again with its `refl fit --tile`", path.display())
}

/// A tile file whose header is read and checked against its length.
struct Opened {
    r: CrcRead<BufReader<std::fs::File>>,
    h: TileHeader,
    path: PathBuf,
}

fn open(path: &Path) -> Result<Opened> {
    let file = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let size = file.metadata().map(|m| m.len()).unwrap_or(0);
    let mut r = CrcRead { inner: BufReader::new(file), crc: crc32fast::Hasher::new() };
    let damaged = |why: String| damaged(path, why);
    let mut head = [0u8; 16];
    r.read_exact(&mut head).map_err(|_| damaged("shorter than its header".into()))?;
    if &head[..8] != MAGIC {
        bail!(damaged("not a tile file".into()));
    }
    let version = u32::from_le_bytes(head[8..12].try_into()?);
    if version != VERSION {
        bail!(damaged(format!("format {version}, this build reads {VERSION}")));
    }
    let len = u32::from_le_bytes(head[12..16].try_into()?);
    if len > MAX_HEADER {
        bail!(damaged("its header is too long".into()));
    }
    let mut json = vec![0u8; len as usize];
    r.read_exact(&mut json).map_err(|_| damaged("truncated in its header".into()))?;
    let h: TileHeader = serde_json::from_slice(&json).map_err(|e| damaged(format!("bad header: {e}")))?;
    let cells = h.grid.len() as u128;
    // Refuse a header whose arrays the file cannot hold before allocating
    // them (in u128: a damaged header's counts may overflow a usize).
    let (n, lights) = (h.points.len() as u128, h.lights as u128);
    let need =
        16 + len as u128 + n * lights * 7 + n * (24 + 4 + 4 + 24) + n * cells * 2 + n * cells.div_ceil(64) * 8 + 4;
    if need != size as u128 {
        bail!(damaged(format!("{size} bytes where its header needs {need}")));
    }
    Ok(Opened { r, h, path: path.to_path_buf() })
}

impl Opened {
    /// Read the tile's samples into `store`, which holds its points (the
    /// tile's own, or the whole grid's for a merge: no second copy), and
    /// return its header and per-point fits.
    fn read_into(self, store: &mut SampleStore) -> Result<(TileHeader, PointMaps)> {
        let Opened { mut r, h, path } = self;
        let damaged = |why: String| damaged(&path, why);
        let held = store.points();
        if h.points.start < held.start || h.points.end > held.end || store.n_lights() != h.lights {
            bail!(damaged(format!("its points {:?} or {} lights are not the capture's", h.points, h.lights)));
        }
        let (n, at) = (h.points.len(), h.points.start - held.start);
        let cells = h.grid.len();
        let short = |e: std::io::Error| damaged(format!("truncated: {e}"));
        for q in 0..h.lights {
            let row = take(&mut r, n, |b: [u8; 1]| b[0]).map_err(short)?;
            store.edit_row(q, |_, flags| flags[at..at + n].copy_from_slice(&row));
        }
        for q in 0..h.lights {
            let row = take(&mut r, n, |b: [u8; 6]| {
                [[b[0], b[1]], [b[2], b[3]], [b[4], b[5]]].map(|x| f16::from_bits(u16::from_le_bytes(x)))
            })
            .map_err(short)?;
            store.edit_row(q, |rho, _| rho[at..at + n].copy_from_slice(&row));
        }
        let kd = triples(take(&mut r, 3 * n, f32::from_le_bytes).map_err(short)?);
        let ks = triples(take(&mut r, 3 * n, f32::from_le_bytes).map_err(short)?);
        let eta = take(&mut r, n, f32::from_le_bytes).map_err(short)?;
        let point_flags = take(&mut r, n, u32::from_le_bytes).map_err(short)?;
        let raw = take(&mut r, 6 * n, u32::from_le_bytes).map_err(short)?;
        let stats = raw
            .chunks_exact(6)
            .map(|s| PointStats {
                usable: s[0],
                saturated: s[1],
                significant: s[2],
                iterations: s[3],
                noise: f32::from_bits(s[4]),
                coverage: f32::from_bits(s[5]),
            })
            .collect();
        let values = take(&mut r, n * cells, |b: [u8; 2]| f16::from_bits(u16::from_le_bytes(b))).map_err(short)?;
        let coverage = take(&mut r, n * cells.div_ceil(64), u64::from_le_bytes).map_err(short)?;
        let crc = r.crc.clone().finalize();
        let mut stored = [0u8; 4];
        r.inner.read_exact(&mut stored).map_err(short)?;
        if u32::from_le_bytes(stored) != crc {
            bail!(damaged("its checksum does not match".into()));
        }
        let tables = TableSet::from_raw(h.grid, n, values, coverage)
            .ok_or_else(|| damaged("its tables do not fit its grid".into()))?;
        Ok((h, PointMaps { kd, ks, eta, flags: point_flags, tables, stats }))
    }
}

/// Read a tile file: its header, and its samples and per-point fits.
pub fn read(path: &Path) -> Result<(TileHeader, TileFit)> {
    let o = open(path)?;
    let mut store = SampleStore::for_points(o.h.points.clone(), o.h.lights);
    let (h, maps) = o.read_into(&mut store)?;
    let t = TileFit { store, maps, drift: h.drift, frames: h.frames, ingest_s: h.ingest_s, points_s: h.points_s };
    Ok((h, t))
}

/// The tiles of `capture` made from `inputs` ([`fingerprint`]): all `N` of
/// one split, each whole, joined into one tile over the grid's `n_points`
/// (the slowest tile's timings), with their headers in order. What is
/// missing, damaged or stale is named, with the command that makes it.
pub fn read_all(capture: &Path, inputs: &str, n_points: usize) -> Result<(Vec<TileHeader>, TileFit)> {
    let dir = capture.join(TILES_DIR);
    let mut markers: Vec<TileHeader> = Vec::new();
    let listing = std::fs::read_dir(&dir).with_context(|| {
        format!("{} has no tiles: fit them first with `refl fit {} --tile K/N`", capture.display(), capture.display())
    })?;
    for e in listing {
        let p = e.with_context(|| format!("listing {}", dir.display()))?.path();
        if p.extension().is_some_and(|x| x == "done") {
            let h: TileHeader =
                serde_json::from_slice(&std::fs::read(&p).with_context(|| format!("reading {}", p.display()))?)
                    .with_context(|| format!("{} is not a tile's done marker", p.display()))?;
            markers.push(h);
        }
    }
    markers.sort_by_key(|h| (h.tile.count, h.tile.index));
    let Some(count) = markers.iter().map(|h| h.tile.count).max() else {
        bail!(
            "{} holds no finished tile: fit them first with `refl fit {} --tile K/N`",
            dir.display(),
            capture.display()
        );
    };
    let splits: std::collections::BTreeSet<u32> = markers.iter().map(|h| h.tile.count).collect();
    if splits.len() > 1 {
        bail!(
            "{} holds tiles of different splits ({}): remove the directory and fit the tiles of one split again",
            dir.display(),
            splits.iter().map(|n| format!("N={n}")).collect::<Vec<_>>().join(", ")
        );
    }
    let missing: Vec<String> =
        (0..count).filter(|k| !markers.iter().any(|h| h.tile.index == *k)).map(|k| format!("{k}/{count}")).collect();
    if !missing.is_empty() {
        bail!(
            "tiles {} of {} are not finished: run `refl fit {} --tile K/N` for each",
            missing.join(", "),
            count,
            capture.display()
        );
    }
    let stale: Vec<String> = markers.iter().filter(|h| h.inputs != inputs).map(|h| h.tile.to_string()).collect();
    if !stale.is_empty() {
        bail!(
            "tiles {} were fitted from other inputs (other settings or --quality, or frames stored since): fit them again",
            stale.join(", ")
        );
    }
    // The tiles' samples go straight into one store over the whole grid,
    // so that a merge holds them once, as a whole fit does.
    let mut store: Option<SampleStore> = None;
    let mut maps = Vec::with_capacity(count as usize);
    let mut headers: Vec<TileHeader> = Vec::with_capacity(count as usize);
    for k in 0..count {
        let tile = Tile { index: k, count };
        let o = open(&tile.file(capture))?;
        let marked = markers.iter().find(|m| m.tile == tile);
        if marked != Some(&o.h) || o.h.inputs != inputs || o.h.points != tile.points(n_points) {
            bail!(
                "{} does not match its done marker or the capture's grid: fit tile {tile} again",
                tile.file(capture).display()
            );
        }
        let whole = store.get_or_insert_with(|| SampleStore::for_points(0..n_points, o.h.lights));
        let (h, m) = o.read_into(whole)?;
        if let Some(first) = headers.first().filter(|f| f.drift != h.drift || f.frames != h.frames) {
            bail!(
                "tiles {} and {tile} read different frames (their frame counts or drift corrections differ): fit them \
                 again",
                first.tile
            );
        }
        headers.push(h);
        maps.push(m);
    }
    let (Some(store), Some(first)) = (store, headers.first()) else { bail!("no tiles to merge") };
    let maps =
        PointMaps::concat(maps).ok_or_else(|| anyhow!("the tiles' NDF tables differ in grid: fit them again"))?;
    let max = |f: fn(&TileHeader) -> f64| headers.iter().map(f).fold(0.0, f64::max);
    let whole = TileFit {
        store,
        maps,
        drift: first.drift,
        frames: first.frames,
        ingest_s: max(|h| h.ingest_s),
        points_s: max(|h| h.points_s),
    };
    Ok((headers, whole))
}

/// Remove the tiles once merged: only this program's own files
/// (`*.tile`, `*.done`), then the directory when that empties it.
pub fn remove(capture: &Path) -> Result<()> {
    let dir = capture.join(TILES_DIR);
    for e in std::fs::read_dir(&dir).with_context(|| format!("listing {}", dir.display()))? {
        let p = e?.path();
        if p.extension().is_some_and(|x| x == "tile" || x == "done") {
            std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
        }
    }
    let _ = std::fs::remove_dir(&dir);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_split_the_grid_into_consecutive_runs() {
        for n in [0usize, 1, 7, 9216] {
            for count in 1..6 {
                let runs: Vec<Range<usize>> = (0..count).map(|k| Tile { index: k, count }.points(n)).collect();
                assert_eq!(runs[0].start, 0);
                assert_eq!(runs.last().unwrap().end, n);
                for w in runs.windows(2) {
                    assert_eq!(w[0].end, w[1].start);
                }
                let (lo, hi) = runs.iter().fold((usize::MAX, 0), |(a, b), r| (a.min(r.len()), b.max(r.len())));
                assert!(hi - lo <= 1, "n {n} count {count}: {runs:?}");
            }
        }
        assert_eq!("2/4".parse::<Tile>(), Ok(Tile { index: 2, count: 4 }));
        for bad in ["4/4", "1/0", "a/3", "3", "-1/2"] {
            assert!(bad.parse::<Tile>().is_err(), "{bad}");
        }
    }

    fn a_tile() -> (TileHeader, TileFit) {
        let grid = NdfGrid::DEFAULT;
        let (points, lights) = (10..14, 5);
        let n = points.len();
        let mut store = SampleStore::for_points(points.clone(), lights);
        for q in 0..lights {
            store.edit_row(q, |rho, flags| {
                for i in 0..n {
                    flags[i] = ((q + i) % 7) as u8;
                    if flags[i] & fit::samples::flag::NO_REFLECTANCE == 0 {
                        rho[i] = [(q * n + i) as f32, 0.5, -1.0].map(f16::from_f32);
                    }
                }
            });
        }
        let mut tables = TableSet::new(grid, n);
        let mut t = brdf::ndf::NdfTable::zeros(grid);
        t.values_mut()[3] = 2.5;
        t.coverage_mut().set(3, true);
        tables.set(2, &t);
        let maps = PointMaps {
            kd: (0..n).map(|k| [k as f32, 0.1, 0.2]).collect(),
            ks: vec![[0.3; 3]; n],
            eta: vec![1.5; n],
            flags: (0..n as u32).collect(),
            tables,
            stats: (0..n as u32).map(|k| PointStats { usable: k, noise: 0.25, ..Default::default() }).collect(),
        };
        let h = TileHeader {
            version: VERSION,
            tile: Tile { index: 1, count: 3 },
            inputs: "abc".into(),
            points,
            lights,
            grid,
            frames: 12,
            ingest_s: 1.0,
            points_s: 2.0,
            drift: None,
        };
        let t = TileFit { store, maps, drift: None, frames: 12, ingest_s: 1.0, points_s: 2.0 };
        (h, t)
    }

    #[test]
    fn a_tile_reads_back_as_written_and_a_damaged_one_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let (h, t) = a_tile();
        let path = write(dir.path(), &h, &t).unwrap();
        assert!(h.tile.marker(dir.path()).exists());
        let (h2, t2) = read(&path).unwrap();
        assert_eq!(h2, h);
        assert_eq!(t2.store, t.store);
        assert_eq!(t2.maps, t.maps);
        let bytes = std::fs::read(&path).unwrap();
        // Truncated anywhere, or one bit flipped past the header: refused.
        for cut in [3, 20, bytes.len() / 2, bytes.len() - 1] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let e = format!("{:#}", read(&path).unwrap_err());
            assert!(e.contains("not a whole tile") && e.contains("--tile"), "{e}");
        }
        for at in [bytes.len() / 2, bytes.len() - 10] {
            let mut b = bytes.clone();
            b[at] ^= 0x10;
            std::fs::write(&path, &b).unwrap();
            let e = format!("{:#}", read(&path).unwrap_err());
            assert!(e.contains("checksum"), "{e}");
        }
    }

    #[test]
    fn a_merge_names_what_is_missing_or_stale() {
        let dir = tempfile::tempdir().unwrap();
        let e = format!("{:#}", read_all(dir.path(), "abc", 20).unwrap_err());
        assert!(e.contains("no tiles") && e.contains("--tile"), "{e}");
        let (h, t) = a_tile();
        write(dir.path(), &h, &t).unwrap();
        let e = format!("{:#}", read_all(dir.path(), "abc", 20).unwrap_err());
        assert!(e.contains("tiles 0/3, 2/3 of 3 are not finished"), "{e}");
        for k in [0, 2] {
            let h = TileHeader { tile: Tile { index: k, count: 3 }, inputs: "old".into(), ..h.clone() };
            write(dir.path(), &h, &t).unwrap();
        }
        let e = format!("{:#}", read_all(dir.path(), "abc", 20).unwrap_err());
        assert!(e.contains("tiles 0/3, 2/3 were fitted from other inputs"), "{e}");
        remove(dir.path()).unwrap();
        assert!(!dir.path().join(TILES_DIR).exists());
    }
}
