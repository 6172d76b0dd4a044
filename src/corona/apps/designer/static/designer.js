// corona designer: the page. Plain JavaScript, no build step, no external files.
// Controls are built from GET /api/parameters (the one parameter specification);
// every change asks the server for the corona picture, the profiles and the
// material (energy split, exports). API: see the README, "The designer".
"use strict";

const $ = (id) => document.getElementById(id);
const SLIDER_STEPS = 1000;

const state = {
  spec: [],            // parameter descriptions from the server
  byName: {},
  values: {},          // name -> string as typed ("" = not given)
  pinned: null,        // material values of B, or null
  exposureA: null,     // EV the server used for A (auto exposure)
  rings: null,         // ring radii of A [degree] per wavelength
  photo: null,         // {image, cx, cy, file}
  material: {},        // last /api/material answer per side
};

// ---------------------------------------------------------------------------
// which controls matter: the specification's own conditions (Parameter.applies), evaluated
// as corona.parameters.Parameter.applies_to does; the page knows no shape or process itself
// ---------------------------------------------------------------------------
function appliesTo(p, v) {
  if (!p.applies || p.applies.length === 0) return true;
  for (const cond of p.applies) {
    if (cond.includes(">")) {
      const [name, limit] = cond.split(">");
      const raw = v[name];
      const x = (raw === undefined || raw === null || String(raw).trim() === "") ? 0 : Number(raw);
      if (Number.isNaN(x) || x > Number(limit)) return true;     // a bad value is reported by its own check
    } else {
      const [name, value] = cond.split("=");
      if (String(v[name] ?? "") === value) return true;
    }
  }
  return false;
}

function relevantNames(v) {
  const out = {};
  for (const p of state.spec) out[p.name] = appliesTo(p, v);
  return out;
}

// ---------------------------------------------------------------------------
// controls
// ---------------------------------------------------------------------------
function sliderToValue(p, s) {
  const sl = p.slider, t = s / SLIDER_STEPS;
  let v = sl.log ? Math.exp(Math.log(sl.low) + t * (Math.log(sl.high) - Math.log(sl.low)))
                 : sl.low + t * (sl.high - sl.low);
  if (p.kind === "int") return String(Math.round(v));
  return String(Number(v.toPrecision(sl.log ? 3 : 4)));
}

function valueToSlider(p, value) {
  const sl = p.slider, v = parseFloat(value);
  if (!isFinite(v)) return 0;
  let t = sl.log ? (Math.log(Math.max(v, 1e-300)) - Math.log(sl.low)) / (Math.log(sl.high) - Math.log(sl.low))
                 : (v - sl.low) / (sl.high - sl.low);
  return Math.round(Math.min(1, Math.max(0, t)) * SLIDER_STEPS);
}

function makeControl(p) {
  const row = document.createElement("div");
  row.className = "ctl";
  row.id = "ctl-" + p.name;
  row.title = `${p.meaning} — allowed ${p.allowed}${p.unit ? " " + p.unit : ""}`;
  const label = document.createElement("label");
  label.className = "name";
  label.textContent = p.name.replace(/_/g, " ");
  label.htmlFor = (p.kind === "choice" ? "sel-" : p.kind === "file" ? "file-" : (p.kind === "string" || p.text) ? "txt-" : "num-") + p.name;
  row.appendChild(label);
  const unit = document.createElement("span");
  unit.className = "unit";
  unit.textContent = p.unit;

  if (p.kind === "choice") {
    const sel = document.createElement("select");
    sel.id = "sel-" + p.name;
    sel.className = "wide";
    for (const c of p.choices) sel.add(new Option(c, c));
    sel.addEventListener("change", () => { state.values[p.name] = sel.value; userChanged(); });
    row.appendChild(sel);
  } else if (p.kind === "string" || p.text) {     // text, or a number that may be a text (a metal, a spectrum)
    const txt = document.createElement("input");
    txt.type = "text"; txt.id = "txt-" + p.name; txt.className = "wide";
    txt.placeholder = p.text ? (p.default === null ? "default" : String(p.default)) : "circle:5:0.5, square:4.43:0.5";
    if (p.text) {
      txt.title = p.text;
      const list = document.createElement("datalist");
      list.id = "list-" + p.name;
      for (const c of p.suggestions || []) list.appendChild(new Option(c, c));
      row.appendChild(list);
      txt.setAttribute("list", list.id);
    }
    txt.addEventListener("change", () => { state.values[p.name] = txt.value; userChanged(); });
    row.appendChild(txt);
  } else if (p.kind === "file") {
    const wrap = document.createElement("span");
    wrap.className = "wide";
    const lab = document.createElement("label");
    lab.className = "file";
    const input = document.createElement("input");
    input.type = "file"; input.id = "file-" + p.name;
    const shown = document.createElement("span");
    shown.id = "shown-" + p.name;
    shown.textContent = " (none)";
    lab.append("upload…", input);
    wrap.append(lab, shown);
    input.addEventListener("change", async () => {
      const f = input.files[0];
      if (!f) return;
      const kind = (p.name === "filename" && state.values.shape === "mask") ? "mask" : "points";
      const ans = await upload(f, kind);
      if (ans) { state.values[p.name] = ans.id; shown.textContent = " " + f.name; userChanged(); }
    });
    row.appendChild(wrap);
  } else {
    const num = document.createElement("input");
    num.type = "number"; num.id = "num-" + p.name; num.step = "any";
    if (p.low !== null) num.min = p.low;
    if (p.high !== null) num.max = p.high;
    if (p.default === null) num.placeholder = "auto";
    if (p.slider) {
      const range = document.createElement("input");
      range.type = "range"; range.id = "slider-" + p.name;
      range.min = 0; range.max = SLIDER_STEPS; range.step = 1;
      range.setAttribute("aria-label", p.name);
      range.addEventListener("input", () => {      // while it moves: a preview of 2-D pictures
        state.values[p.name] = num.value = sliderToValue(p, range.value);
        userChanged(true);
      });
      range.addEventListener("change", () => userChanged());   // let go: the exact picture
      row.appendChild(range);
    } else {
      const gap = document.createElement("span");
      row.appendChild(gap);
    }
    num.addEventListener("change", () => {
      state.values[p.name] = num.value;
      if (p.slider) $("slider-" + p.name).value = valueToSlider(p, num.value);
      userChanged();
    });
    row.appendChild(num);
  }
  if ((p.kind === "float" || p.kind === "int") && !p.text) {
    if (p.default === null) {
      const clear = document.createElement("button");
      clear.type = "button"; clear.className = "clear"; clear.textContent = "×";
      clear.title = "not set: " + p.meaning;
      clear.addEventListener("click", () => { state.values[p.name] = ""; showValue(p); userChanged(); });
      row.appendChild(clear);
    } else {
      row.appendChild(unit);
    }
  } else if (p.kind === "file") {
    const clear = document.createElement("button");
    clear.type = "button"; clear.className = "clear"; clear.textContent = "×"; clear.title = "no file";
    clear.addEventListener("click", () => { state.values[p.name] = ""; showValue(p); userChanged(); });
    row.appendChild(clear);
  } else {
    row.appendChild(document.createElement("span"));
  }
  return row;
}

function showValue(p) {
  const v = state.values[p.name] ?? "";
  if (p.kind === "choice") $("sel-" + p.name).value = v || p.default;
  else if (p.kind === "string" || p.text) $("txt-" + p.name).value = v;
  else if (p.kind === "file") $("shown-" + p.name).textContent = v ? " " + v : " (none)";
  else {
    $("num-" + p.name).value = v;
    if (p.slider) $("slider-" + p.name).value = valueToSlider(p, v === "" ? p.slider.low : v);
  }
}

function setDefaults() {
  for (const p of state.spec) state.values[p.name] = p.default === null ? "" : String(p.default);
}

function applyValues(obj) {
  for (const [k, v] of Object.entries(obj)) if (k in state.byName) state.values[k] = v === null ? "" : String(v);
}

function showAll() {
  for (const p of state.spec) showValue(p);
  for (const p of state.spec) {       // knobs that mean nothing for this layer: dimmed, and not sent
    const row = $("ctl-" + p.name), on = appliesTo(p, state.values);
    row.classList.toggle("inactive", !on);
    row.dataset.active = on ? "1" : "0";
    row.title = `${p.meaning} — allowed ${p.allowed}${p.unit ? " " + p.unit : ""}` +
      (on ? "" : ` — not used here (used with ${p.used_with})`);
  }
}

// ---------------------------------------------------------------------------
// queries
// ---------------------------------------------------------------------------
function query(groups, values, extra) {
  const qs = new URLSearchParams();
  for (const p of state.spec) {
    if (!groups.includes(p.group)) continue;
    const v = values[p.name];
    if (v === undefined || v === "" || v === null) continue;
    if (p.group === "material" && !appliesTo(p, values)) continue;
    if (String(v) === String(p.default)) continue;   // the server knows the defaults
    qs.set(p.name, v);
  }
  for (const [k, v] of Object.entries(extra || {})) qs.set(k, v);
  return qs.toString();
}

function materialOf(values) {
  const out = {};
  for (const p of state.spec) if (p.group === "material") out[p.name] = values[p.name];
  return out;
}

// One request in flight per view; newer requests replace the waiting one.
class Channel {
  constructor(handle) { this.handle = handle; this.busy = false; this.next = null; }
  request(url, ctx) {
    if (this.busy) { this.next = [url, ctx]; return; }
    this.busy = true;
    busy.start();
    const t0 = performance.now();
    fetch(url).then(async (res) => {
      const ms = performance.now() - t0;
      if (!res.ok) {
        let msg = res.statusText;
        try { msg = (await res.json()).error; } catch (e) { /* not JSON */ }
        showError(msg);
        return;
      }
      await this.handle(res, ms, ctx);
    }).catch((err) => showError("the designer server did not answer (" + err.message + ")"))
      .finally(() => {
        this.busy = false;
        busy.end();
        if (this.next) { const [u, c] = this.next; this.next = null; this.request(u, c); }
      });
  }
}

// ---------------------------------------------------------------------------
// busy indicator: while requests are in flight for more than a moment, the server's
// progress (GET /api/progress: what it computes, and the table builds' progress bars)
// ---------------------------------------------------------------------------
const busy = {
  inflight: 0, timer: null, since: 0,
  start() {
    if (this.inflight++ === 0) { this.since = performance.now(); this.schedule(400); }
  },
  end() {
    if (--this.inflight <= 0) {
      this.inflight = 0;
      clearTimeout(this.timer); this.timer = null;
      $("busy").hidden = true;
    }
  },
  schedule(ms) { clearTimeout(this.timer); this.timer = setTimeout(() => this.poll(), ms); },
  async poll() {
    if (this.inflight === 0) return;
    try {
      const res = await fetch("/api/progress", { cache: "no-store" });
      if (res.ok && this.inflight > 0) this.show(await res.json());
    } catch (e) { /* the next poll tries again */ }
    if (this.inflight > 0) this.schedule(300);
  },
  show(data) {
    const bars = data.bars || [], jobs = data.jobs || [];
    const bar = bars.find((b) => b.total) || bars[0];
    const secs = ((performance.now() - this.since) / 1000).toFixed(0);
    let text = jobs.length ? "computing " + [...new Set(jobs.map((j) => j.what))].join(", ") : "waiting for the server";
    const prog = $("busy-bar");
    if (bar) {
      const what = bar.desc || "building tables";
      const count = `${Math.round(bar.n)}${bar.total ? " / " + Math.round(bar.total) : ""} ${bar.unit}`;
      text = `${what}: ${count}`;
      if (bar.total) { prog.max = bar.total; prog.value = bar.n; } else prog.removeAttribute("value");
    } else prog.removeAttribute("value");         // indeterminate
    $("busy-text").textContent = `${text} · ${secs} s`;
    $("busy").hidden = false;
  },
};

// a new sphere radius: the server answered with a preview and builds the exact table in the
// background; show its progress and ask again once GET /api/progress lists no build
let watchingBuild = false;
async function watchBuild() {
  if (watchingBuild) return;
  watchingBuild = true;
  busy.start();
  try {
    for (;;) {
      await new Promise((r) => setTimeout(r, 400));
      try {
        const res = await fetch("/api/progress", { cache: "no-store" });
        if (res.ok && !((await res.json()).builds || []).length) break;
      } catch (e) { /* the next poll tries again */ }
    }
  } finally {
    watchingBuild = false;
    busy.end();
  }
  changed(state.preview);          // picture A asks for B again when comparing
}

const timings = {};
function showTiming(what, ms) {
  timings[what] = ms;
  $("status").textContent = Object.entries(timings).map(([k, v]) => `${k} ${v.toFixed(0)} ms`).join(" · ");
}

let errorShown = false;
function showError(msg) {
  $("error").textContent = msg;
  $("error").hidden = false;
  errorShown = true;
}
function clearError() {
  if (errorShown) { $("error").hidden = true; errorShown = false; }
}

async function digest(buf) {
  if (!(window.crypto && crypto.subtle)) {        // plain sum, where WebCrypto is absent
    let h = 0; const b = new Uint8Array(buf);
    for (let i = 0; i < b.length; i++) h = (h * 31 + b[i]) >>> 0;
    return h.toString(16);
  }
  const d = new Uint8Array(await crypto.subtle.digest("SHA-256", buf));
  return Array.from(d.slice(0, 8), (x) => x.toString(16).padStart(2, "0")).join("");
}

function pictureHandler(side) {
  return async (res, ms) => {
    const buf = await res.arrayBuffer();
    const img = $("corona-" + side);
    const old = img.dataset.url;
    const url = URL.createObjectURL(new Blob([buf], { type: "image/png" }));
    const ev = parseFloat(res.headers.get("X-Corona-Exposure"));
    const field = parseFloat(res.headers.get("X-Corona-Field"));
    img.dataset.digest = await digest(buf);
    img.onload = () => { img.dataset.version = String(Number(img.dataset.version) + 1); if (old) URL.revokeObjectURL(old); };
    img.src = url;
    img.dataset.url = url;
    const preview = res.headers.get("X-Corona-Preview") === "1";
    const building = res.headers.get("X-Corona-Building") === "1";
    img.dataset.preview = preview ? "1" : "0";
    img.dataset.building = building ? "1" : "0";
    $("cap-" + side).textContent = `±${field.toPrecision(3)}° · ${ev.toFixed(1)} EV${state.values.exposure ? "" : " (auto)"}`
      + (building ? " · preview: a coarse Mie table while the exact one builds; the exact picture follows"
        : preview ? " · preview: half the pixels while the slider moves, exact when let go" : "");
    if (building) watchBuild();
    if (side === "a") {
      clearError();
      showTiming("corona", ms);
      state.exposureA = ev;
      state.fieldA = field;
      if (state.pinned) requestB();
    }
  };
}

const chanA = new Channel(pictureHandler("a"));
const chanB = new Channel(pictureHandler("b"));
const chanProfiles = new Channel(async (res, ms, ctx) => {
  const data = await res.json();
  showTiming("profiles", ms);
  state.profiles = state.profiles || {};
  state.profiles[ctx] = data;
  if (ctx === "a") { state.rings = data.rings; drawPhoto(); }
  drawProfiles();
});
const chanProfilesB = new Channel(chanProfiles.handle);
const chanMaterial = new Channel(async (res, ms, ctx) => {
  const data = await res.json();
  showTiming("energy", ms);
  state.material[ctx] = data;
  drawEnergy(ctx, data);
  $("energy-" + ctx).classList.remove("stale");
  if (ctx === "a") showExport();
});
const chanMaterialB = new Channel(chanMaterial.handle);

function requestB() {
  const vals = { ...state.values, ...state.pinned };
  const extra = state.values.exposure ? {} : { exposure: state.exposureA.toFixed(4) };
  if (!state.values.field && state.fieldA) extra.field = state.fieldA;
  chanB.request("/api/corona.png?" + query(["material", "light"], vals, extra), "b");
  chanProfilesB.request("/api/profiles?" + query(["material", "light"], vals, extra), "b");
  chanMaterialB.request("/api/material?" + query(["material"], vals), "b");
  $("energy-b").classList.add("stale");
}

// the preset menu says "custom" once a knob is edited by hand
function userChanged(preview = false) {
  $("preset").value = "custom";
  changed(preview);
}

let scheduled = false;
function changed(preview = false) {
  showAll();
  state.preview = preview;             // the last change decides: a slider let go asks for the exact picture
  if (scheduled) return;
  scheduled = true;
  requestAnimationFrame(() => { scheduled = false; update(); });
}

function update() {
  const q = query(["material", "light"], state.values);
  chanA.request("/api/corona.png?" + q + (state.preview ? "&preview=1" : ""), "a");
  chanProfiles.request("/api/profiles?" + q, "a");
  chanMaterial.request("/api/material?" + query(["material"], state.values), "a");
  $("energy-a").classList.add("stale");            // until the new numbers arrive (the table can take a while)
  const kq = query(["material", "kernel"], state.values);
  $("kernel-png").href = "/api/kernel.png?" + kq;
  $("kernel-exr").href = "/api/kernel.exr?" + kq;
  chanKernel.request("/api/kernel_info?" + kq, "a");
  // the look in the address: copy it to share it, load it to restore it
  const look = query(["material", "light", "kernel"], state.values);
  history.replaceState(null, "", look ? "?" + look : location.pathname);
}

const chanKernel = new Channel(async (res) => {
  const k = await res.json();
  const share = Math.floor(1000 * k.share_min) / 10;
  const view = k.view === "reflection" ? "reflection in the mirror" : "seen through the layer";
  $("kernel-info").textContent = `${k.kernel_size} × ${k.kernel_size} px at ${Number(k.pixel_scale.toPrecision(3))}°/px ` +
    `(±${Number(k.half_width.toPrecision(3))}°, ${view}): holds ${share.toFixed(1)} % of the lobe's energy`;
  $("kernel-warning").textContent = k.warning || "";
  $("kernel-warning").hidden = !k.warning;
  $("kernel-info").dataset.share = String(k.share_min);
});

// ---------------------------------------------------------------------------
// energy split, profiles, exports
// ---------------------------------------------------------------------------
function drawEnergy(side, m) {
  const row = $("energy-" + side);
  const parts = [["coherent", m.coherent_transmittance], ["lobe", m.diffuse_transmittance],
                 ["specular", m.specular_reflection], ["lobe-reflected", m.lobe_reflection],
                 ["diffuse-reflected", m.reflectance], ["absorbed", m.absorbed]]
    .filter(([k, v]) => v > 0 || ["coherent", "lobe", "absorbed"].includes(k));
  row.innerHTML = "";
  const tag = document.createElement("b");
  tag.textContent = side.toUpperCase();
  const bar = document.createElement("div");
  bar.className = "bar";
  for (const [k, v] of parts) {
    const s = document.createElement("span");
    s.className = "k-" + k;
    s.style.width = (100 * Math.max(0, v)).toFixed(2) + "%";
    s.title = `${k}: ${v.toFixed(4)}`;
    bar.appendChild(s);
  }
  const legend = document.createElement("div");
  legend.className = "legend";
  legend.id = "energy-legend-" + side;
  legend.textContent = parts.map(([k, v]) => `${k.replace("-", " ")} ${v.toFixed(3)}`).join(" · ") +
    ` · F_a ${m.area_fraction.toFixed(3)}` + (m.substrate && m.substrate !== "none" ? ` · on ${m.substrate}` : "");
  row.append(tag, bar, legend);
}

const CURVES = [["T_a", "#f0b429", "T_a [1/sr]"], ["T_s", "#4a90d9", "T_s"], ["lobe", "#e8e8e8", "lobe F_a T_a T_s [1/sr]"]];

function drawProfiles() {
  const cv = $("profiles"), g = cv.getContext("2d");
  const W = cv.width, H = cv.height, L = 54, R = 10, T = 26, B = 34;
  g.fillStyle = "#0b0b0c"; g.fillRect(0, 0, W, H);
  const sets = [["a", state.profiles && state.profiles.a, []]];
  if (state.pinned && state.profiles && state.profiles.b) sets.push(["b", state.profiles.b, [5, 4]]);
  if (!sets[0][1]) return;
  let top = 0, xmax = 0;
  for (const [, d] of sets) {
    if (!d) continue;
    xmax = Math.max(xmax, d.angle[d.angle.length - 1]);
    for (const [k] of CURVES) for (const y of d[k]) top = Math.max(top, y);
  }
  top = Math.pow(10, Math.ceil(Math.log10(top || 1)));
  const bottom = top * 1e-7;
  const X = (x) => L + (W - L - R) * x / xmax;
  const Y = (y) => T + (H - T - B) * (Math.log10(top) - Math.log10(Math.max(y, bottom))) / (Math.log10(top) - Math.log10(bottom));
  g.strokeStyle = "#2a2a2a"; g.fillStyle = "#888"; g.font = "11px system-ui"; g.lineWidth = 1;
  for (let e = Math.log10(bottom); e <= Math.log10(top) + 1e-9; e++) {
    const y = Y(Math.pow(10, e));
    g.beginPath(); g.moveTo(L, y); g.lineTo(W - R, y); g.stroke();
    g.fillText("1e" + Math.round(e), 8, y + 4);
  }
  const step = niceStep(xmax / 8);
  for (let x = 0; x <= xmax + 1e-9; x += step) {
    g.beginPath(); g.moveTo(X(x), T); g.lineTo(X(x), H - B); g.stroke();
    g.fillText(Number(x.toPrecision(3)) + "°", X(x) - 8, H - B + 14);
  }
  g.fillText("angle from the light at 550 nm", W / 2 - 80, H - 6);
  for (const [side, d, dash] of sets) {
    if (!d) continue;
    for (const [k, color] of CURVES) {
      for (const suffix of d.isotropic ? [""] : ["", "_y"]) {
        const ys = d[k + suffix];
        g.strokeStyle = color; g.lineWidth = side === "a" ? 1.6 : 1.2;
        g.setLineDash(suffix ? [2, 3] : dash);
        g.beginPath();
        ys.forEach((y, i) => { const px = X(d.angle[i]), py = Y(y); i ? g.lineTo(px, py) : g.moveTo(px, py); });
        g.stroke();
      }
    }
  }
  g.setLineDash([]);
  let lx = L + 10;
  for (const [, color, name] of CURVES) {
    g.fillStyle = color; g.fillRect(lx, 8, 14, 3);
    g.fillStyle = "#bbb"; g.fillText(name, lx + 18, 13);
    lx += g.measureText(name).width + 34;
  }
  if (sets.length > 1) { g.fillStyle = "#bbb"; g.fillText("solid: A, dashed: B", lx, 13); }
  else if (!sets[0][1].isotropic) { g.fillStyle = "#bbb"; g.fillText("dotted: along y", lx, 13); }
}

function niceStep(x) {
  const e = Math.pow(10, Math.floor(Math.log10(x)));
  for (const m of [1, 2, 5, 10]) if (m * e >= x) return m * e;
  return 10 * e;
}

function showExport() {
  const m = state.material.a;
  if (!m) return;
  $("export-text").value = m[$("export-kind").value];
}

// ---------------------------------------------------------------------------
// photograph: drop zone, ring overlay, fit
// ---------------------------------------------------------------------------
function loadPhoto(file) {
  if (!file || !/^image\/(png|jpeg)$/.test(file.type)) { showError("the photograph must be a PNG or JPEG image"); return; }
  const img = new Image();
  img.onload = () => {
    state.photo = { image: img, file, cx: img.naturalWidth / 2, cy: img.naturalHeight / 2 };
    brightest(state.photo);
    $("photo-canvas").hidden = false;
    $("fit").disabled = false;
    drawPhoto();
  };
  img.src = URL.createObjectURL(file);
}

function brightest(ph) {   // start the rings on the brightest spot (the light)
  const w = 160, h = Math.max(1, Math.round(160 * ph.image.naturalHeight / ph.image.naturalWidth));
  const c = document.createElement("canvas"); c.width = w; c.height = h;
  const g = c.getContext("2d"); g.drawImage(ph.image, 0, 0, w, h);
  const px = g.getImageData(0, 0, w, h).data;
  let best = -1, bi = 0;
  for (let i = 0; i < w * h; i++) { const s = px[4 * i] + px[4 * i + 1] + px[4 * i + 2]; if (s > best) { best = s; bi = i; } }
  ph.cx = ((bi % w) + 0.5) * ph.image.naturalWidth / w;
  ph.cy = (Math.floor(bi / w) + 0.5) * ph.image.naturalHeight / h;
}

function drawPhoto() {
  const ph = state.photo;
  if (!ph) return;
  const cv = $("photo-canvas"), g = cv.getContext("2d");
  const W = cv.width, H = Math.round(W * ph.image.naturalHeight / ph.image.naturalWidth);
  cv.height = H;
  g.drawImage(ph.image, 0, 0, W, H);
  const s = W / ph.image.naturalWidth, cx = ph.cx * s, cy = ph.cy * s;
  const fov = parseFloat($("photo-fov").value);
  if (!state.rings || !(fov > 0 && fov < 180)) return;
  const f = (W / 2) / Math.tan(fov * Math.PI / 360);       // pinhole focal length [pixels]
  const colours = { "450": "#6aa0ff", "550": "#6fdc6f", "650": "#ff6a6a" };
  g.lineWidth = 1;
  for (const [lam, radii] of Object.entries(state.rings)) {
    g.strokeStyle = colours[lam] || "#fff";
    for (const th of radii) {
      g.beginPath(); g.arc(cx, cy, f * Math.tan(th * Math.PI / 180), 0, 2 * Math.PI); g.stroke();
    }
  }
  g.strokeStyle = "#fff"; g.beginPath(); g.moveTo(cx - 5, cy); g.lineTo(cx + 5, cy); g.moveTo(cx, cy - 5); g.lineTo(cx, cy + 5); g.stroke();
}

async function upload(file, kind) {
  const res = await fetch(`/api/upload?kind=${kind}&name=${encodeURIComponent(file.name)}`, { method: "POST", body: file });
  const data = await res.json();
  if (!res.ok) { showError(data.error); return null; }
  return data;
}

async function fit() {
  const ph = state.photo;
  if (!ph) return;
  $("fit-status").textContent = "fitting…";
  const up = await upload(ph.file, "photo");
  if (!up) { $("fit-status").textContent = ""; return; }
  const res = await fetch("/api/fit", { method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ photo: up.id, fov: parseFloat($("photo-fov").value), parameters: materialOf(state.values) }) });
  const data = await res.json();
  if (!res.ok) { $("fit-status").textContent = data.error; return; }
  applyValues(data.parameters);
  $("preset").value = "custom";
  $("fit-status").textContent = "fitted: " + Object.entries(data.parameters).map(([k, v]) => `${k} ${typeof v === "number" ? v.toPrecision(4) : v}`).join(", ");
  changed();
}

// ---------------------------------------------------------------------------
// start
// ---------------------------------------------------------------------------
async function start() {
  const res = await fetch("/api/parameters");
  const spec = await res.json();
  state.spec = spec.parameters;
  for (const p of state.spec) state.byName[p.name] = p;
  for (const p of state.spec) {
    const box = p.group === "material" ? "material-controls" : p.group === "light" ? "light-controls" : "kernel-controls";
    $(box).appendChild(makeControl(p));
  }
  setDefaults();
  const sel = $("preset");
  for (const [name, pr] of Object.entries(spec.presets)) {
    const o = new Option(name, name); o.title = pr.about; sel.add(o);
  }
  const custom = new Option("custom", "custom");
  custom.title = "the knobs as edited (not a preset)";
  sel.add(custom);
  sel.addEventListener("change", () => {
    const pr = spec.presets[sel.value];
    if (!pr) return;
    setDefaults();
    applyValues(pr.material); applyValues(pr.view);
    changed();
  });
  sel.value = Object.keys(spec.presets)[0];
  applyValues(spec.presets[sel.value].material); applyValues(spec.presets[sel.value].view);
  // a look from the address (?radius=8&...): the defaults and these values, as the page wrote it
  const given = [...new URLSearchParams(location.search)].filter(([k]) => k in state.byName);
  if (given.length) {
    setDefaults();
    for (const [k, v] of given) state.values[k] = v;
    const here = query(["material", "light", "kernel"], state.values);
    sel.value = "custom";
    for (const [name, pr] of Object.entries(spec.presets)) {
      const vals = {};
      for (const p of state.spec) vals[p.name] = p.default === null ? "" : String(p.default);
      for (const [k, v] of Object.entries({ ...pr.material, ...pr.view })) vals[k] = v === null ? "" : String(v);
      if (query(["material", "light", "kernel"], vals) === here) sel.value = name;
    }
  }

  $("pin").addEventListener("click", () => {
    state.pinned = materialOf(state.values);
    $("fig-b").hidden = false; $("energy-b").hidden = false; $("unpin").hidden = false;
    state.profiles = state.profiles || {}; state.profiles.b = null;
    if (state.exposureA !== null) requestB();
  });
  $("unpin").addEventListener("click", () => {
    state.pinned = null;
    $("fig-b").hidden = true; $("energy-b").hidden = true; $("unpin").hidden = true;
    drawProfiles();
  });
  $("export-kind").addEventListener("change", showExport);
  $("copy").addEventListener("click", () => { $("export-text").select(); navigator.clipboard && navigator.clipboard.writeText($("export-text").value).catch(() => {}); });
  const drop = $("drop");
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => { e.preventDefault(); drop.classList.remove("over"); loadPhoto(e.dataTransfer.files[0]); });
  $("photo-file").addEventListener("change", (e) => loadPhoto(e.target.files[0]));
  $("photo-fov").addEventListener("input", drawPhoto);
  $("photo-canvas").addEventListener("click", (e) => {
    const cv = $("photo-canvas"), r = cv.getBoundingClientRect(), ph = state.photo;
    const s = ph.image.naturalWidth / r.width;
    ph.cx = (e.clientX - r.left) * s; ph.cy = (e.clientY - r.top) * s;
    drawPhoto();
  });
  $("fit").addEventListener("click", fit);
  changed();
}

// for tests and scripts: the page's own relevance rule, from the specification
window.corona = { appliesTo: (name, values) => appliesTo(state.byName[name], values), relevantNames, state };

start().catch((err) => showError("the page could not start: " + err.message));
