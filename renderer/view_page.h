#pragma once
// The one page of `isotrace view` (renderer/view.cpp), compiled into the binary: nothing is
// fetched from anywhere else. Controls: one range input (class "iso") and one colour input per
// iso-surface (for one coloured by data: a map select, class "map", and its range, class "lo" and
// "hi", instead of the colour), one range input (class "slice") per slice plane, a clip plane of
// the volumes per axis (checkboxes of class "clip-on" and "clip-flip", a range input of class
// "clip"), a time slider (#time-step, class "time") when a volume changes over time, the integrator
// (#integrator), Save (#save); the image (#view) takes orbit
// (drag), pan (shift-drag or right-drag) and zoom (wheel). Frames come as server-sent events.

namespace iso {

inline constexpr const char* kViewPage = R"HTML(<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>isotrace view</title>
<link rel="icon" href="data:,">
<style>
  body { font: 14px system-ui, sans-serif; margin: 0; background: #1e1f22; color: #ddd; display: flex; }
  #panel { width: 280px; padding: 12px; box-sizing: border-box; }
  #stage { flex: 1; padding: 12px; }
  #view { display: block; max-width: 100%; image-rendering: auto; cursor: grab; background: #000; user-select: none; }
  label { display: block; margin-top: 10px; }
  .surface { margin-bottom: 14px; border-top: 1px solid #444; padding-top: 8px; }
  .iso { width: 100%; }
  .figures { margin-top: 8px; color: #aaa; font-variant-numeric: tabular-nums; }
  button, select { font: inherit; }
  #saved { color: #9c9; word-break: break-all; margin-top: 6px; }
  #error { color: #e88; }
</style>
</head>
<body>
<div id="panel">
  <div><b>isotrace view</b> <span id="scene"></span></div>
  <label>integrator <select id="integrator"></select></label>
  <label><input type="checkbox" id="denoise"> denoise</label>
  <div id="time"></div>
  <div id="surfaces"></div>
  <div id="slices"></div>
  <div id="clips"></div>
  <div class="figures">spp <span id="spp">0</span> / <span id="target">0</span> ·
    <span id="mrays">0</span> Mrays/s · <span id="seconds">0</span> s</div>
  <div><button id="save">Save</button></div>
  <div id="saved"></div>
  <div id="error"></div>
  <p style="color:#888">drag: orbit · shift-drag or right-drag: pan · wheel: zoom</p>
</div>
<div id="stage"><img id="view" alt="the rendered image" draggable="false"></div>
<script>
"use strict";
let state = null;
const $ = (id) => document.getElementById(id);

// One request in flight per kind; the newest change waits for it and replaces older ones.
const pending = new Map();
const busy = new Set();
function send(kind, change) {
  pending.set(kind, change);
  if (!busy.has(kind)) flush(kind);
}
function flush(kind) {
  if (!pending.has(kind)) return;
  const change = pending.get(kind);
  pending.delete(kind);
  busy.add(kind);
  fetch("/api/state", {method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(change)})
    .then((r) => r.json().then((body) => {
      if (!r.ok) { $("error").textContent = body.error || ("HTTP " + r.status); return; }
      $("error").textContent = "";
      state = body;
    }))
    .catch((e) => { $("error").textContent = String(e); })
    .finally(() => { busy.delete(kind); flush(kind); });
}

// A range input from min to max in `steps` steps.
function slider(className, min, max, steps, label) {
  const range = document.createElement("input");
  range.type = "range";
  range.className = className;
  range.min = min;
  range.max = max;
  range.step = max > min ? (max - min) / steps : 1;
  range.setAttribute("aria-label", label);
  return range;
}

function showState(s) {
  state = s;
  $("scene").textContent = s.scene.split("/").pop();
  const select = $("integrator");
  if (select.options.length === 0)
    for (const name of s.integrators) select.add(new Option(name, name));
  select.value = s.integrator;
  $("denoise").checked = !!s.denoise;
  $("target").textContent = s.spp_target;
  const box = $("surfaces");
  if (box.children.length !== s.surfaces.length) {
    box.textContent = "";
    for (const f of s.surfaces) {
      const div = document.createElement("div");
      div.className = "surface";
      const label = document.createElement("label");
      const name = document.createElement("span");
      name.textContent = f.label + " = ";
      const value = document.createElement("span");
      value.className = "value";
      label.append(name, value);
      const range = slider("iso", f.min, f.max, 10000, "iso value of " + f.label);
      range.dataset.surface = f.index;
      range.addEventListener("input", () => {
        value.textContent = Number(range.value).toPrecision(5);
        send("iso" + f.index, {surface: f.index, value: Number(range.value)});
      });
      if (f.color_by) {  // coloured by data: the map and its range
        const map = document.createElement("select");
        map.className = "map";
        for (const name of s.maps) map.add(new Option(name, name));
        // A map of the scene's own stops ("custom") stays until a named map is chosen.
        if (!s.maps.includes(f.color_by.map)) map.add(new Option(f.color_by.map, f.color_by.map));
        const lo = document.createElement("input"), hi = document.createElement("input");
        lo.type = hi.type = "number";
        lo.className = "lo";
        hi.className = "hi";
        lo.style.width = hi.style.width = "7em";
        const sendMap = () => {
          if (s.maps.includes(map.value))
            send("colorby" + f.index, {surface: f.index, color_by: {map: map.value, range: [Number(lo.value), Number(hi.value)]}});
        };
        for (const e of [map, lo, hi]) e.addEventListener("change", sendMap);
        const note = document.createElement("div");
        note.textContent = "coloured by " + f.color_by.field;
        div.append(label, range, note, map, lo, hi);
      } else {
        const colour = document.createElement("input");
        colour.type = "color";
        colour.className = "color";
        colour.dataset.surface = f.index;
        colour.addEventListener("input", () => send("color" + f.index, {surface: f.index, color: colour.value}));
        div.append(label, range, colour);
      }
      box.append(div);
    }
  }
  const time = $("time");
  if (s.time && !time.children.length) {  // volumes that change over time: one step at a time
    const label = document.createElement("label");
    const range = slider("time", 0, s.time.steps - 1, s.time.steps - 1, "time step");
    range.id = "time-step";
    range.step = 1;
    const shown = document.createElement("span");
    shown.className = "value";
    label.append("time step ", shown, " of " + s.time.steps);
    range.addEventListener("input", () => {
      shown.textContent = range.value;
      send("time", {time: Number(range.value)});
    });
    time.append(label, range);
  }
  if (s.time) {
    const range = $("time-step");
    if (document.activeElement !== range) range.value = s.time.step;
    time.querySelector(".value").textContent = range.value;
  }
  const slices = $("slices");
  if (slices.children.length !== s.slices.length) {
    slices.textContent = "";
    for (const f of s.slices) {
      const div = document.createElement("div");
      div.className = "surface";
      const label = document.createElement("label");
      label.textContent = f.label;
      const range = slider("slice", f.min, f.max, 1000, "position of " + f.label);
      range.addEventListener("input", () => send("slice" + f.index, {slice: f.index, position: Number(range.value)}));
      div.append(label, range);
      slices.append(div);
    }
  }
  const clips = $("clips");
  if (clips.children.length !== s.clip.length) {
    clips.textContent = "";
    for (const c of s.clip) {
      const div = document.createElement("div");
      div.className = "surface";
      const on = document.createElement("input"), flip = document.createElement("input");
      on.type = flip.type = "checkbox";
      on.className = "clip-on";
      flip.className = "clip-flip";
      on.dataset.axis = flip.dataset.axis = c.axis;
      const label = document.createElement("label");
      label.append(on, " clip " + c.axis + " ", flip, " flip");
      const range = slider("clip", c.min, c.max, 1000, "clip plane across " + c.axis);
      range.dataset.axis = c.axis;
      const sendClip = () => send("clip" + c.axis, {clip: {axis: c.axis, on: on.checked, flip: flip.checked, position: Number(range.value)}});
      on.addEventListener("change", sendClip);
      flip.addEventListener("change", sendClip);
      range.addEventListener("input", sendClip);
      div.append(label, range);
      clips.append(div);
    }
  }
  s.clip.forEach((c, i) => {
    const div = clips.children[i];
    const range = div.querySelector(".clip");
    if (document.activeElement !== range) range.value = c.position;
    div.querySelector(".clip-on").checked = c.on;
    div.querySelector(".clip-flip").checked = c.flip;
  });
  s.slices.forEach((f, i) => {
    const range = slices.children[i].querySelector(".slice");
    if (document.activeElement !== range) range.value = f.position;
  });
  s.surfaces.forEach((f, i) => {
    const div = box.children[i];
    const range = div.querySelector(".iso");
    if (document.activeElement !== range) {
      range.value = f.value;
      div.querySelector(".value").textContent = Number(f.value).toPrecision(5);
    }
    if (f.color_by) {
      for (const [cls, v] of [["map", f.color_by.map], ["lo", f.color_by.range[0]], ["hi", f.color_by.range[1]]]) {
        const e = div.querySelector("." + cls);
        if (document.activeElement !== e) e.value = v;
      }
    } else {
      div.querySelector(".color").value = f.color;
    }
  });
  $("error").textContent = s.error || "";
}

function loadState() {
  return fetch("/api/state").then((r) => r.json()).then(showState);
}

$("integrator").addEventListener("change", () => send("integrator", {integrator: $("integrator").value}));
$("denoise").addEventListener("change", () => send("denoise", {denoise: $("denoise").checked}));
$("save").addEventListener("click", () => {
  $("saved").textContent = "saving…";
  fetch("/api/save", {method: "POST"}).then((r) => r.json().then((body) => {
    $("saved").textContent = r.ok ? "saved " + body.files.join(", ") : "";
    if (!r.ok) $("error").textContent = body.error;
  })).catch((e) => { $("error").textContent = String(e); });
});

// Camera: orbit about the look-at point, pan both, zoom along the view direction.
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => mul(a, 1 / Math.hypot(a[0], a[1], a[2]));
function rotate(v, axis, angle) {  // Rodrigues
  const k = norm(axis), c = Math.cos(angle), s = Math.sin(angle);
  return add(add(mul(v, c), mul(cross(k, v), s)), mul(k, dot(k, v) * (1 - c)));
}
function moveCamera(dx, dy, pan) {
  if (!state) return;
  const c = state.camera;
  let pos = c.position, at = c.look_at;
  const up = norm(c.up);
  const back = sub(pos, at);
  const dist = Math.hypot(back[0], back[1], back[2]);
  const right = norm(cross(mul(back, -1), up));
  if (pan) {
    const scale = dist * Math.tan(c.fov * Math.PI / 360) * 2 / $("view").clientHeight;
    const shift = add(mul(right, -dx * scale), mul(norm(cross(right, mul(back, -1))), dy * scale));
    pos = add(pos, shift);
    at = add(at, shift);
  } else {
    let b = rotate(back, up, -dx * 0.01);
    const b2 = rotate(b, right, -dy * 0.01);
    if (Math.abs(dot(norm(b2), up)) < 0.99) b = b2;  // not over the pole
    pos = add(at, b);
  }
  state.camera = {position: pos, look_at: at, up: c.up, fov: c.fov};
  send("camera", {camera: state.camera});
}
const view = $("view");
let drag = null;
view.addEventListener("contextmenu", (e) => e.preventDefault());
view.addEventListener("mousedown", (e) => { drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2}; e.preventDefault(); });
window.addEventListener("mouseup", () => { drag = null; });
window.addEventListener("mousemove", (e) => {
  if (!drag) return;
  moveCamera(e.clientX - drag.x, e.clientY - drag.y, drag.pan);
  drag.x = e.clientX;
  drag.y = e.clientY;
});
view.addEventListener("wheel", (e) => {
  e.preventDefault();
  if (!state) return;
  const c = state.camera;
  const back = sub(c.position, c.look_at);
  const f = Math.exp(Math.sign(e.deltaY) * 0.1);
  state.camera = {position: add(c.look_at, mul(back, f)), look_at: c.look_at, up: c.up, fov: c.fov};
  send("camera", {camera: state.camera});
}, {passive: false});

// The frames received lately, for a look from the console (and the browser test): version,
// samples, preview.
const frameLog = [];
loadState().then(() => {
  const events = new EventSource("/api/events");
  events.addEventListener("frame", (e) => {
    const f = JSON.parse(e.data);
    frameLog.push({version: f.version, spp: f.spp, preview: f.preview});
    if (frameLog.length > 256) frameLog.shift();
    view.src = f.image;
    view.style.width = f.display_width + "px";
    $("spp").textContent = f.spp;
    $("target").textContent = f.spp_target;
    $("mrays").textContent = f.mrays.toFixed(2);
    $("seconds").textContent = f.seconds.toFixed(2);
    view.dataset.version = f.version;
    // Another tab changed something: take its state.
    if (!state || f.version !== state.version) loadState();
  });
});
</script>
</body>
</html>
)HTML";

}  // namespace iso
