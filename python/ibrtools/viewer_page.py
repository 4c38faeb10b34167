"""The page ``ibr-view`` serves (ibrtools/viewer.py): one self-contained HTML document, no file
and no script from anywhere else. It only displays frames; the engine renders them.

Controls: drag = orbit around the scene's centre, shift + drag = look around, wheel = move
towards / away from the centre, W A S D (Q E: down / up) = fly; while the camera moves frames
are asked at half size and refined to full size 200 ms after it stops; one request is in flight
at a time and only the newest pose waits (older ones are dropped). The map shows the input
cameras (grey), the current one (red) and the key poses of the path (blue), seen from above.

Self-test (used by tests/test_viewer.py in headless Chromium): ``&selftest=drag`` drags once
after the first frame; the page records what it displayed on ``<body>``: ``data-frames`` (frames
shown), ``data-poses`` (their cam_from_world, JSON), ``data-sizes``, ``data-ms`` (the render times).
"""
from __future__ import annotations

PAGE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>ibr-view</title>
<style>
 body { margin: 0; font: 13px sans-serif; background: #222; color: #ddd; }
 #frame { position: absolute; left: 0; top: 0; cursor: grab; image-rendering: auto; }
 #panel { position: absolute; top: 0; padding: 8px; width: 260px; }
 #panel button, #panel select, #panel input { margin: 2px 0; font-size: 12px; }
 #map { background: #111; border: 1px solid #444; }
 .row { margin: 6px 0; }
</style></head>
<body data-frames="0">
<img id="frame" alt="frame" draggable="false">
<div id="panel">
 <div class="row">method <select id="method"></select> overlay <select id="overlay">
  <option value="none">none</option><option value="holes">holes</option><option value="method">method choice</option></select></div>
 <div class="row">snap to <select id="snap"><option value="">input view...</option></select></div>
 <div class="row" id="time">-</div>
 <canvas id="map" width="240" height="240"></canvas>
 <div class="row">path: <button id="key">record key pose</button> <span id="nkeys">0</span> keys<br>
  frames <input id="nframes" type="number" value="60" min="2" max="10000" style="width:5em">
  <button id="preview">preview</button><br>
  name <input id="pname" value="path" style="width:8em"> <button id="save">save</button>
  <input id="load" type="file" accept=".json"><div id="pathmsg"></div></div>
 <div class="row">drag: orbit; shift+drag: look; wheel: dolly; WASD QE: fly</div>
</div>
<script>
"use strict";
const Q = new URLSearchParams(location.search), TOKEN = Q.get("t") || "";
const CLIENT = Math.random().toString(36).slice(2);
const img = document.getElementById("frame"), body = document.body;
let info = null, intr = null, R = null, eye = null, centre = null, up = null;
let seq = 0, inFlight = false, wanted = null, shown = null, lastMove = 0, refineTimer = null;
const keys = [], held = {};
const shownPoses = [], shownSizes = [], shownMs = [];

// --- small linear algebra (row-major 3x3 as arrays of rows) ---------------------------------
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const norm = a => scale(a, 1 / Math.hypot(a[0], a[1], a[2]));
const mulv = (M, v) => [dot(M[0], v), dot(M[1], v), dot(M[2], v)];
const transpose = M => [[M[0][0], M[1][0], M[2][0]], [M[0][1], M[1][1], M[2][1]], [M[0][2], M[1][2], M[2][2]]];
const matmul = (A, B) => { const T = transpose(B); return A.map(r => [dot(r, T[0]), dot(r, T[1]), dot(r, T[2])]); };
function axisAngle(a, t) {  // rotation matrix about unit axis a by t radians
  const c = Math.cos(t), s = Math.sin(t), C = 1 - c, [x, y, z] = a;
  return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
          [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
          [z * x * C - y * s, z * y * C + x * s, c + z * z * C]];
}
function orthonormal(M) {  // Gram-Schmidt on the rows (keeps the camera rigid for the server's check)
  const z = norm(M[2]), x = norm(sub(M[0], scale(z, dot(M[0], z)))), y = cross(z, x);
  return [x, y, z];
}
function camDict(w, h) {
  const t = scale(mulv(R, eye), -1), s = w / intr.width;
  return {model: "pinhole", width: w, height: h, fx: intr.fx * s, fy: intr.fy * (h / intr.height),
          cx: intr.cx * s, cy: intr.cy * (h / intr.height),
          cam_from_world: [[...R[0], t[0]], [...R[1], t[1]], [...R[2], t[2]], [0, 0, 0, 1]]};
}
function setPose(d) {  // from a camera dict (intrinsics too)
  intr = {width: d.width, height: d.height, fx: d.fx, fy: d.fy, cx: d.cx, cy: d.cy};
  const M = d.cam_from_world;
  R = orthonormal([M[0].slice(0, 3), M[1].slice(0, 3), M[2].slice(0, 3)]);
  const t = [M[0][3], M[1][3], M[2][3]];
  eye = scale(mulv(transpose(R), t), -1);
}
// world rotation G of the camera about a point p: R' = R G^T, eye' = p + G (eye - p)
function rotateAbout(G, p) { R = orthonormal(matmul(R, transpose(G))); eye = add(p, mulv(G, sub(eye, p))); }

// --- frames ---------------------------------------------------------------------------------
function request(full) {
  if (!info) return;
  const w = full ? intr.width : Math.max(8, Math.round(intr.width / 2));
  const h = full ? intr.height : Math.max(8, Math.round(intr.height / 2));
  wanted = {pose: camDict(intr.width, intr.height), w: w, h: h,
            method: document.getElementById("method").value, overlay: document.getElementById("overlay").value};
  pump();
}
function pump() {
  if (inFlight || !wanted) return;
  const r = wanted; wanted = null; inFlight = true; const s = ++seq;
  const url = "/frame?t=" + encodeURIComponent(TOKEN) + "&client=" + CLIENT + "&seq=" + s + "&w=" + r.w + "&h=" + r.h +
    "&method=" + r.method + "&overlay=" + r.overlay + "&fmt=" + (r.w === intr.width ? "png" : "jpeg") +
    "&pose=" + encodeURIComponent(JSON.stringify(r.pose));
  fetch(url).then(resp => {
    if (resp.status === 204) return null;
    if (!resp.ok) return resp.text().then(t => { throw new Error(t); });
    const ms = resp.headers.get("X-Render-Ms");
    return resp.blob().then(b => ({b: b, ms: ms}));
  }).then(got => {
    if (!got) { inFlight = false; pump(); return; }
    const u = URL.createObjectURL(got.b);
    img.onload = () => {
      URL.revokeObjectURL(u);
      img.width = intr.width; img.height = intr.height;
      document.getElementById("panel").style.left = (intr.width + 8) + "px";
      shown = r; shownPoses.push(r.pose.cam_from_world); shownSizes.push([r.w, r.h]); shownMs.push(+got.ms);
      body.dataset.frames = String(shownPoses.length);
      body.dataset.poses = JSON.stringify(shownPoses);
      body.dataset.sizes = JSON.stringify(shownSizes);
      body.dataset.ms = JSON.stringify(shownMs);
      document.getElementById("time").textContent = r.w + " x " + r.h + ": " + got.ms + " ms";
      inFlight = false; drawMap(); pump();
      if (shownPoses.length === 1 && Q.get("selftest") === "drag") selftestDrag();
    };
    img.src = u;
  }).catch(e => { document.getElementById("time").textContent = "error: " + e.message; body.dataset.error = e.message;
                  inFlight = false; });
}
function moved() {
  lastMove = performance.now(); request(false);
  clearTimeout(refineTimer); refineTimer = setTimeout(() => request(true), 200);
}

// --- controls -------------------------------------------------------------------------------
let drag = null;
img.addEventListener("mousedown", e => { drag = {x: e.clientX, y: e.clientY, shift: e.shiftKey}; e.preventDefault(); });
window.addEventListener("mouseup", () => { drag = null; });
window.addEventListener("mousemove", e => {
  if (!drag || !info) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y; drag.x = e.clientX; drag.y = e.clientY;
  const right = R[0];  // the camera's x axis in world coordinates
  if (drag.shift) { rotateAbout(axisAngle(up, -dx * 0.004), eye); rotateAbout(axisAngle(right, -dy * 0.004), eye); }
  else { rotateAbout(axisAngle(up, -dx * 0.008), centre); rotateAbout(axisAngle(right, -dy * 0.008), centre); }
  moved();
});
img.addEventListener("wheel", e => {
  const d = sub(centre, eye), f = e.deltaY < 0 ? 0.1 : -0.1; eye = add(eye, scale(d, f)); moved(); e.preventDefault();
}, {passive: false});
window.addEventListener("keydown", e => { held[e.key.toLowerCase()] = true; });
window.addEventListener("keyup", e => { held[e.key.toLowerCase()] = false; });
setInterval(() => {
  if (!info) return;
  const step = 0.02 * Math.hypot(...sub(centre, eye)); let m = [0, 0, 0];
  if (held.w) m = add(m, R[2]); if (held.s) m = sub(m, R[2]);
  if (held.d) m = add(m, R[0]); if (held.a) m = sub(m, R[0]);
  if (held.e) m = add(m, up); if (held.q) m = sub(m, up);
  if (m[0] || m[1] || m[2]) { eye = add(eye, scale(m, step)); moved(); }
}, 50);
document.getElementById("method").onchange = () => request(true);
document.getElementById("overlay").onchange = () => request(true);
document.getElementById("snap").onchange = e => {
  const v = info.views.find(x => x.name === e.target.value) || info.targets.find(x => x.name === e.target.value);
  if (v) { setPose(v.camera); request(true); }
};
function selftestDrag() {
  const r = img.getBoundingClientRect(), x = r.left + r.width / 2, y = r.top + r.height / 2;
  img.dispatchEvent(new MouseEvent("mousedown", {clientX: x, clientY: y, bubbles: true}));
  for (let i = 1; i <= 5; i++) window.dispatchEvent(new MouseEvent("mousemove", {clientX: x + 8 * i, clientY: y, bubbles: true}));
  window.dispatchEvent(new MouseEvent("mouseup", {clientX: x + 40, clientY: y, bubbles: true}));
}

// --- path: key poses, interpolation (positions linear, rotations slerp), save / load ----------
function toQuat(M) {
  const t = M[0][0] + M[1][1] + M[2][2]; let q;
  if (t > 0) { const s = Math.sqrt(t + 1) * 2; q = [0.25 * s, (M[2][1] - M[1][2]) / s, (M[0][2] - M[2][0]) / s, (M[1][0] - M[0][1]) / s]; }
  else if (M[0][0] > M[1][1] && M[0][0] > M[2][2]) { const s = Math.sqrt(1 + M[0][0] - M[1][1] - M[2][2]) * 2;
    q = [(M[2][1] - M[1][2]) / s, 0.25 * s, (M[0][1] + M[1][0]) / s, (M[0][2] + M[2][0]) / s]; }
  else if (M[1][1] > M[2][2]) { const s = Math.sqrt(1 + M[1][1] - M[0][0] - M[2][2]) * 2;
    q = [(M[0][2] - M[2][0]) / s, (M[0][1] + M[1][0]) / s, 0.25 * s, (M[1][2] + M[2][1]) / s]; }
  else { const s = Math.sqrt(1 + M[2][2] - M[0][0] - M[1][1]) * 2;
    q = [(M[1][0] - M[0][1]) / s, (M[0][2] + M[2][0]) / s, (M[1][2] + M[2][1]) / s, 0.25 * s]; }
  return q;
}
function fromQuat(q) {
  const [w, x, y, z] = q;
  return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]];
}
function slerp(a, b, t) {
  let d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
  if (d < 0) { b = b.map(v => -v); d = -d; }
  if (d > 0.9995) { const q = a.map((v, i) => v + t * (b[i] - v)); const n = Math.hypot(...q); return q.map(v => v / n); }
  const th = Math.acos(d), s = Math.sin(th), wa = Math.sin((1 - t) * th) / s, wb = Math.sin(t * th) / s;
  return a.map((v, i) => wa * v + wb * b[i]);
}
function interpolated(n) {
  if (keys.length < 2) return keys.map(k => k.pose);
  const out = [];
  for (let i = 0; i < n; i++) {
    const u = i / (n - 1) * (keys.length - 1), j = Math.min(Math.floor(u), keys.length - 2), t = u - j;
    const a = keys[j], b = keys[j + 1];
    R = orthonormal(fromQuat(slerp(toQuat(a.R), toQuat(b.R), t))); eye = add(scale(a.eye, 1 - t), scale(b.eye, t));
    out.push(camDict(intr.width, intr.height));
  }
  return out;
}
document.getElementById("key").onclick = () => {
  keys.push({R: R.map(r => r.slice()), eye: eye.slice(), pose: camDict(intr.width, intr.height)});
  document.getElementById("nkeys").textContent = keys.length; drawMap();
};
document.getElementById("preview").onclick = () => {
  const n = +document.getElementById("nframes").value, poses = interpolated(n); let i = 0;
  const tick = () => { if (i >= poses.length) return; setPose(poses[i++]); request(true); setTimeout(tick, 120); };
  tick();
};
document.getElementById("save").onclick = () => {
  const saveR = R, saveEye = eye;
  const poses = interpolated(+document.getElementById("nframes").value).map((p, i) => ({...p, name: "frame_" + String(i).padStart(4, "0")}));
  R = saveR; eye = saveEye;
  fetch("/path?t=" + encodeURIComponent(TOKEN), {method: "POST", body: JSON.stringify({name: document.getElementById("pname").value, poses: poses})})
    .then(r => r.text()).then(t => { document.getElementById("pathmsg").textContent = t; });
};
document.getElementById("load").onchange = e => {
  const f = e.target.files[0]; if (!f) return;
  f.text().then(t => {
    keys.length = 0;
    for (const p of JSON.parse(t)) { setPose(p); keys.push({R: R.map(r => r.slice()), eye: eye.slice(), pose: p}); }
    document.getElementById("nkeys").textContent = keys.length; if (keys.length) { setPose(keys[0].pose); request(true); }
  });
};

// --- the map: cameras seen from above (the plane normal to up) --------------------------------
function drawMap() {
  const c = document.getElementById("map"), g = c.getContext("2d"); g.clearRect(0, 0, c.width, c.height);
  const a = norm(Math.abs(up[0]) < 0.9 ? cross(up, [1, 0, 0]) : cross(up, [0, 1, 0])), b = cross(up, a);
  const all = info.views.map(v => v.camera).concat(info.targets.map(t => t.camera));
  const pos = d => { const M = d.cam_from_world, Rr = [M[0].slice(0, 3), M[1].slice(0, 3), M[2].slice(0, 3)];
                     return scale(mulv(transpose(Rr), [M[0][3], M[1][3], M[2][3]]), -1); };
  const pts = all.map(pos).concat([eye]);
  const xs = pts.map(p => dot(sub(p, centre), a)), ys = pts.map(p => dot(sub(p, centre), b));
  const ext = Math.max(1e-9, ...xs.map(Math.abs), ...ys.map(Math.abs)) * 1.15, k = (c.width / 2) / ext;
  const P = p => [c.width / 2 + dot(sub(p, centre), a) * k, c.height / 2 - dot(sub(p, centre), b) * k];
  const frustum = (p, fwd, colour) => {
    const [x, y] = P(p), f = [dot(fwd, a), -dot(fwd, b)], n = Math.hypot(f[0], f[1]) || 1, l = 12;
    const fx = f[0] / n, fy = f[1] / n;
    g.strokeStyle = colour; g.beginPath(); g.moveTo(x, y);
    g.lineTo(x + l * (fx - 0.5 * fy), y + l * (fy + 0.5 * fx)); g.lineTo(x + l * (fx + 0.5 * fy), y + l * (fy - 0.5 * fx));
    g.closePath(); g.stroke();
  };
  for (const d of all) frustum(pos(d), d.cam_from_world[2].slice(0, 3), "#888");
  for (const kp of keys) frustum(kp.eye, kp.R[2], "#48f");
  frustum(eye, R[2], "#f44");
}

fetch("/scene.json?t=" + encodeURIComponent(TOKEN)).then(r => r.json()).then(j => {
  info = j; up = j.up; centre = j.centre; setPose(j.start);
  const ms = document.getElementById("method");
  for (const m of j.methods) ms.add(new Option(m, m));
  ms.value = j.method;
  const sn = document.getElementById("snap");
  for (const v of j.views.concat(j.targets)) sn.add(new Option(v.name, v.name));
  request(true);
});
</script></body></html>
"""
