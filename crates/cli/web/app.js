// The rig page: follows the daemon's board (server-sent events), shows
// the camera's latest frame, starts and cancels captures with the token.
const $ = (id) => document.getElementById(id);
const tokenBox = $("token");
tokenBox.value = localStorage.getItem("reflectometer-token") || "";
tokenBox.addEventListener("change", () => localStorage.setItem("reflectometer-token", tokenBox.value.trim()));

function say(text, cls) {
  $("msg").textContent = text;
  $("msg").className = cls || "";
}

async function post(path, body) {
  const r = await fetch(path, {
    method: "POST",
    headers: { "Content-Type": "application/json", "Authorization": "Bearer " + tokenBox.value.trim() },
    body: body ? JSON.stringify(body) : "{}",
  });
  const text = await r.text();
  if (!r.ok) throw new Error(`${r.status}: ${text}`);
  return text ? JSON.parse(text) : {};
}

// "steps=32 grid=48 no_synthesis" as the preset's overrides.
function overrides(text) {
  const o = {};
  for (const word of text.split(/\s+/).filter((w) => w)) {
    const [k, v] = word.split("=");
    o[k.replace(/-/g, "_")] = v === undefined ? true : Number(v);
  }
  return o;
}

$("start").addEventListener("click", async () => {
  try {
    const body = { sample: $("sample").value.trim(), quality: $("quality").value, overrides: overrides($("settings").value) };
    const r = await post("/api/capture", body);
    say(`capturing into ${r.out}`);
  } catch (e) { say(`refused: ${e.message}`, "error"); }
});
$("cancel").addEventListener("click", async () => {
  try {
    const r = await post("/api/cancel");
    say(r.cancelled ? "cancelling: the rig stops, every frame is kept (resume with capture --resume)" : "nothing to cancel");
  } catch (e) { say(`refused: ${e.message}`, "error"); }
});

const fmt = (v, d = 3) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));
let frameSeq = -1;
let shownResult = null;

let lastState = null;

function show(b) {
  // A job that ended may have made a calibration: read the rig again.
  if (lastState !== null && lastState !== b.state && b.state === "idle") loadRig();
  lastState = b.state;
  $("state").textContent = b.state;
  document.body.dataset.state = b.state;
  $("job").textContent = b.job ? `${b.job.sample || ""} → ${b.job.out || ""}` : "";
  const f = b.frames;
  if (f) {
    $("frames-text").textContent = `${f.done}/${f.total} (${fmt(f.rate_hz, 1)}/s, about ${fmt(f.eta_s, 0)} s left)`;
    $("frames-bar").style.width = `${(100 * f.done) / Math.max(1, f.total)}%`;
  } else { $("frames-text").textContent = "–"; $("frames-bar").style.width = "0"; }
  const fit = b.fit;
  if (fit) {
    const eta = fit.eta_s === null || fit.eta_s === undefined ? "" : `, about ${fmt(fit.eta_s, 0)} s left`;
    $("fit-text").textContent = `${fit.stage}${fit.within ? " (" + fit.within + ")" : ""} ${fit.done}/${fit.total}${eta}`;
    $("fit-bar").style.width = `${(100 * fit.done) / Math.max(1, fit.total)}%`;
  } else { $("fit-text").textContent = "–"; $("fit-bar").style.width = "0"; }
  const l = b.link;
  $("link").textContent = l
    ? `${l.commands} commands, ${l.retransmits} retransmits, ${l.stale_replies} stale replies, ${l.bad_frames} bad frames, mean round trip ${fmt(l.mean_rtt_us, 0)} µs`
    : "–";
  if (b.frame_seq !== frameSeq) {
    frameSeq = b.frame_seq;
    if (frameSeq > 0) $("frame").src = `/api/frame.png?seq=${frameSeq}`;
  }
  $("frame-gain").textContent = b.frame_seq > 0 ? `(shown ×${fmt(b.frame_gain, 1)}; red: clipped)` : "";
  $("log").innerHTML = "";
  for (const line of b.log) {
    const span = document.createElement("span");
    span.className = line.kind;
    span.textContent = `${line.t_s.toFixed(1).padStart(7)} s  ${line.text}\n`;
    $("log").appendChild(span);
  }
  $("log").scrollTop = $("log").scrollHeight;
  showResult(b.result);
}

function showResult(r) {
  const key = r ? JSON.stringify([r.dir, r.exit, r.gltf, !!r.eval, r.problems]) : null;
  if (key === shownResult) return;
  shownResult = key;
  $("result-section").hidden = !r;
  if (!r) return;
  $("result-head").textContent = r.exit === 0
    ? `${r.sample || ""}: ${r.dir}`
    : `${r.sample || ""}: ended with exit ${r.exit}${r.message ? " — " + r.message : ""}`;
  $("result-problems").textContent = (r.problems || []).join("; ");
  $("renders").innerHTML = "";
  for (const name of r.renders) {
    const link = document.createElement("a");
    link.href = `/result/renders/${encodeURIComponent(name)}?d=${encodeURIComponent(r.dir)}`;
    link.target = "_blank";
    const img = document.createElement("img");
    img.src = link.href;
    img.title = `${name} (click for full size)`;
    link.appendChild(img);
    $("renders").appendChild(link);
  }
  $("eval").innerHTML = r.eval ? evalTable(r.eval) : (r.exit === 0 ? "<p>evaluating…</p>" : "");
  if (r.gltf) {
    import("/viewer.js")
      .then((v) => v.show(`/result/gltf/${r.gltf}?d=${encodeURIComponent(r.dir)}`, $("viewer")))
      .then(() => { $("viewer-note").textContent = "drag to turn, wheel to zoom"; })
      .catch((e) => { $("viewer-note").textContent = `3D viewer unavailable: ${e.message} (three.js is installed with npm ci --prefix web)`; });
  }
}

function evalTable(ev) {
  const cols = [["render_rel_rmse", "render error"], ["ndf_rel_l2_observed", "NDF error (observed)"], ["ndf_rel_l2_full", "NDF error (hemisphere)"]];
  let h = `<table><tr><th>model</th>${cols.map((c) => `<th>${c[1]}</th>`).join("")}</tr>`;
  for (const [name, s] of Object.entries(ev.models)) {
    h += `<tr><td>${name}</td>${cols.map((c) => `<td>${fmt(s[c[0]], 4)}</td>`).join("")}</tr>`;
  }
  h += "</table>";
  if (!ev.ground_truth) h += "<p>No ground truth: the figures compare the models with the measured samples.</p>";
  return h;
}

async function loadStatic() {
  try {
    const s = await (await fetch("/api/samples")).json();
    for (const b of s.builtin) {
      const o = document.createElement("option");
      o.value = b.name;
      o.label = b.about;
      $("samples").appendChild(o);
    }
    for (const q of s.qualities) {
      const o = document.createElement("option");
      o.value = o.textContent = q;
      if (q === "balanced") o.selected = true;
      $("quality").appendChild(o);
    }
  } catch (e) { say(`cannot list samples: ${e.message}`, "error"); }
  await loadRig();
}

async function loadRig() {
  try {
    const rig = await (await fetch("/api/rig")).json();
    $("rig").textContent = `rig: ${rig.name} (${rig.kind})`;
    const c = rig.calibration;
    $("calib").textContent = c
      ? `calibration ${c.id}, ${c.age_days === null ? "age unknown" : c.age_days + " days old"}${c.geometric ? "" : ", no geometric calibration"}`
      : `calibration: ${rig.problem || "none"}`;
  } catch (e) { $("rig").textContent = "rig: unknown"; }
}

loadStatic();
const events = new EventSource("/api/events");
events.addEventListener("state", (e) => show(JSON.parse(e.data)));
events.onerror = () => say("connection to the daemon lost; retrying…", "warning");
events.onopen = () => { if ($("msg").textContent.startsWith("connection")) say(""); };
