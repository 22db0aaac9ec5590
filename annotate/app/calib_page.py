"""The calibration page itself: one HTML document with its script, no external assets.

Left: the camera's frame (the server's picture; after a solve, optionally the picture of what
the error costs). Right: the aerial image, or the table of surveyed points. Both images zoom
with the mouse wheel around the pointer (up to 16x, for pixel precision) and pan by dragging;
a click without dragging picks the image pixel under the pointer. Click a point in the frame,
then its partner on the aerial image (or a row of the table): the pair is sent to the server,
which journals it before answering. ``window.calib`` exposes the views' transforms (``toScreen``,
``zoomTo``) so that a browser test clicks where a user would.
"""

PAGE = r"""<!doctype html>
<html><head><meta charset="utf-8"><title>s2p calibrate-camera</title>
<style>
body{font:14px sans-serif;margin:8px;background:#222;color:#eee}
#bar{display:flex;gap:8px;align-items:center;flex-wrap:wrap;margin-bottom:6px}
#panes{display:flex;gap:8px}
.view{position:relative;overflow:hidden;width:49vw;height:68vh;background:#111;cursor:crosshair}
.inner{position:absolute;left:0;top:0;transform-origin:0 0}
.inner img{display:block;image-rendering:pixelated;user-select:none;-webkit-user-drag:none}
.inner svg{position:absolute;left:0;top:0;pointer-events:none;overflow:visible}
#survey{width:49vw;height:68vh;overflow:auto;background:#111}
#survey tr.used{color:#8c8} #survey tr:hover{background:#333;cursor:pointer}
pre{white-space:pre-wrap;background:#111;padding:6px;max-height:22vh;overflow:auto}
#msg{color:#fc6}
</style></head><body>
<div id="bar">
 camera <select id="camera"></select>
 elevation (m, optional) <input id="elev" size="6">
 <button id="undo">Undo</button><button id="solve">Solve</button><button id="save">Save</button>
 <label><input type="checkbox" id="showcost"> cost picture</label>
 <span id="count"></span> <span id="msg"></span>
</div>
<div id="panes">
 <div class="view" id="frameview"><div class="inner"><img id="frameimg"><svg id="framesvg"></svg></div></div>
 <div class="view" id="aerialview"><div class="inner"><img id="aerialimg"><svg id="aerialsvg"></svg></div></div>
 <div id="survey" hidden><table id="surveytable"></table></div>
</div>
<pre id="report"></pre>
<script>
"use strict";
let S = null, pending = null;
const $ = id => document.getElementById(id);
function msg(t){ $("msg").textContent = t || ""; }
const esc = t => String(t).replace(/[&<>"']/g, c => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;",
  "'": "&#39;"})[c]);

function makeView(name, view, img, svg){
  const v = {name, view, img, svg, inner: view.querySelector(".inner"), s: 1, ox: 0, oy: 0, w: 1, h: 1};
  v.apply = () => { v.inner.style.transform = `translate(${v.ox}px,${v.oy}px) scale(${v.s})`; draw(); };
  v.fit = () => { const r = view.getBoundingClientRect();
    v.s = Math.min(r.width / v.w, r.height / v.h); v.ox = (r.width - v.w * v.s) / 2;
      v.oy = (r.height - v.h * v.s) / 2; v.apply(); };
  v.toImage = (cx, cy) => { const r = view.getBoundingClientRect();
    return [(cx - r.left - v.ox) / v.s, (cy - r.top - v.oy) / v.s]; };
  v.toScreen = (u, y) => { const r = view.getBoundingClientRect();
    return [r.left + v.ox + u * v.s, r.top + v.oy + y * v.s]; };
  v.zoomTo = (u, y, s) => { const r = view.getBoundingClientRect(); v.s = s; v.ox = r.width / 2 - u * s;
    v.oy = r.height / 2 - y * s; v.apply(); };
  img.onload = () => { v.w = img.naturalWidth; v.h = img.naturalHeight;
    svg.setAttribute("width", v.w); svg.setAttribute("height", v.h); if (!v.loaded) { v.loaded = true; v.fit();
      } else v.apply(); };
  view.addEventListener("wheel", e => { e.preventDefault();
    const [u, y] = v.toImage(e.clientX, e.clientY); const r = view.getBoundingClientRect();
    const fit = Math.min(r.width / v.w, r.height / v.h);
    v.s = Math.max(fit / 2, Math.min(16, v.s * (e.deltaY < 0 ? 1.25 : 0.8)));
    v.ox = e.clientX - r.left - u * v.s; v.oy = e.clientY - r.top - y * v.s; v.apply(); }, {passive: false});
  let drag = null;
  view.addEventListener("mousedown", e => { drag = {x: e.clientX, y: e.clientY, ox: v.ox, oy: v.oy, moved: false}; });
  window.addEventListener("mousemove", e => { if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 4) drag.moved = true;
    if (drag.moved) { v.ox = drag.ox + dx; v.oy = drag.oy + dy; v.apply(); } });
  window.addEventListener("mouseup", e => { if (!drag) return; const d = drag; drag = null;
    if (!d.moved && view.contains(e.target)) { const [u, y] = v.toImage(e.clientX, e.clientY); picked(name, u, y);
      } });
  return v;
}
const V = {frame: makeView("frame", $("frameview"), $("frameimg"), $("framesvg")),
           aerial: makeView("aerial", $("aerialview"), $("aerialimg"), $("aerialsvg"))};

function circle(svg, u, y, s, colour, label){
  const r = 7 / s;
  svg.insertAdjacentHTML("beforeend",
    `<circle cx="${u}" cy="${y}" r="${r}" fill="none" stroke="${colour}" stroke-width="${2 / s}"/>`
    + (label ? `<text x="${u + r * 1.3}" y="${y - r}" fill="${colour}" font-size="${13 / s}">`
               + `${esc(label)}</text>` : ""));
}
function draw(){
  if (!S) return;
  const cam = $("camera").value;
  for (const k of ["frame", "aerial"]) V[k].svg.innerHTML = "";
  for (const p of S.pairs) {
    if (p.camera === cam) circle(V.frame.svg, p.u, p.v, V.frame.s, "#4f4", p.name);
    if (p.ax !== null) circle(V.aerial.svg, p.ax, p.ay, V.aerial.s, "#4f4", p.name);
  }
  if (pending) circle(V.frame.svg, pending[0], pending[1], V.frame.s, "#ff0", "?");
  $("count").textContent = `${S.pairs.filter(p => p.camera === cam).length} pairs for ${cam}` +
    (pending ? " - now click its partner" : "");
  for (const tr of document.querySelectorAll("#surveytable tr[data-name]"))
    tr.className = S.pairs.some(p => p.camera === cam && p.name === tr.dataset.name) ? "used" : "";
}
async function api(path, body){
  const r = await fetch(path, {method: body === undefined ? "GET" : "POST",
    headers: {"content-type": "application/json"}, body: body === undefined ? undefined : JSON.stringify(body)});
  const d = await r.json();
  if (!r.ok) { msg(d.error || r.statusText); throw new Error(d.error); }
  return d;
}
function frameSrc(){
  const cam = $("camera").value;
  const kind = $("showcost").checked && S && S.solved.includes(cam) ? "img/cost/" : "img/frame/";
  return kind + encodeURIComponent(cam) + "?t=" + Date.now();
}
function elevation(){
  const t = $("elev").value.trim(); if (!t) return null;
  const z = Number(t); if (!Number.isFinite(z)) { msg("the elevation must be a number of metres");
    throw new Error("elev"); }
  return z;
}
async function sendPair(extra){
  const body = Object.assign({camera: $("camera").value, u: pending[0], v: pending[1], z: elevation()}, extra);
  S = await api("api/pair", body); pending = null; $("elev").value = ""; msg(""); draw();
}
async function picked(name, u, y){
  if (!S) return;
  if (name === "frame") { pending = [u, y]; draw(); return; }
  if (!pending) { msg("click the point in the frame first"); return; }
  await sendPair({ax: u, ay: y});
}
$("undo").onclick = async () => { if (pending) { pending = null; draw(); return; } S = await api("api/undo", {});
  draw(); };
$("solve").onclick = async () => { msg("solving..."); const d = await api("api/solve", {});
  $("report").textContent = d.report; S = d.state; msg("solved"); V.frame.img.src = frameSrc(); };
$("save").onclick = async () => { const d = await api("api/save", {});
  $("report").textContent += "\n" + d.lines.join("\n"); msg("saved"); };
$("showcost").onchange = () => { V.frame.img.src = frameSrc(); };
$("camera").onchange = () => { pending = null; V.frame.loaded = false; V.frame.img.src = frameSrc(); };
async function start(){
  S = await api("api/state");
  for (const c of Object.keys(S.cameras)) $("camera").insertAdjacentHTML("beforeend", `<option>${esc(c)}</option>`);
  V.frame.img.src = frameSrc();
  if (S.aerial) V.aerial.img.src = "img/aerial";
  else { $("aerialview").hidden = true; $("survey").hidden = false; }
  const t = $("surveytable");
  t.insertAdjacentHTML("beforeend", "<tr><th>name</th><th>x</th><th>y</th><th>z</th></tr>");
  for (const p of S.survey) t.insertAdjacentHTML("beforeend",
    `<tr data-name="${esc(p.name)}"><td>${esc(p.name)}</td><td>${p.x}</td><td>${p.y}</td><td>${p.z ?? ""}</td></tr>`);
  t.onclick = async e => { const tr = e.target.closest("tr[data-name]"); if (!tr) return;
    if (!pending) { msg("click the point in the frame first"); return; } await sendPair({survey: tr.dataset.name}); };
  if (S.note) msg(S.note);
  draw(); window.calib.ready = true;
}
window.calib = {views: V, ready: false,
  toScreen: (k, u, y) => V[k].toScreen(u, y), zoomTo: (k, u, y, s) => V[k].zoomTo(u, y, s),
  state: () => S};
start();
</script></body></html>
"""
