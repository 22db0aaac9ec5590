"""The large camera view of the annotation page: an anywidget showing the server's picture of
the current frame (frame_image.py) in an ``<img>``. A click on it (not a drag) sends
{"click": [u, v], "camera": ..., "frame": ...}: the image pixel (x right, y down, pixel
centres at +0.5), computed from the element's size, so every click lands, repeated or not.

Editing like CVAT: the wheel zooms at the pointer, a drag pans (zoomed in), ``0`` (or "fit")
fits, ``+``/``-`` zoom; a drag of the selected box's base (the dashed footprint) sends
{"drag": [[u0, v0], [u1, v1]]} (move it on the ground), a drag of its handle (the dot ahead
of it) {"rotate_to": [u, v]} (turn it to face there); brightness and contrast sliders
filter the picture in the browser.

The picture, the frame and the camera travel in one trait (``view``), so the page never shows
a picture under another frame's number: ``data-frame`` on the image is the frame it shows.
"""

from __future__ import annotations

import base64

import anywidget
import traitlets

_ESM = r"""
function render({ model, el }) {
  const wrap = document.createElement('div');
  wrap.className = 's2p-frame';
  const bar = document.createElement('div');
  bar.className = 's2p-frame-bar';
  const cap = document.createElement('div');
  cap.className = 's2p-frame-cap';
  cap.dataset.testid = 'frame-caption';
  const tools = document.createElement('span');
  tools.className = 's2p-tools';
  tools.innerHTML =
    '<label title="brightness">☀<input type="range" min="30" max="250" value="100" data-testid="brightness">' +
    '</label><label title="contrast">◐<input type="range" min="30" max="300" value="100" ' +
    'data-testid="contrast"></label>' +
    '<button data-testid="fit" title="fit the picture (0); wheel zooms, drag pans">fit</button>';
  bar.append(cap, tools);
  const stage = document.createElement('div');
  stage.className = 's2p-stage';
  const zoom = document.createElement('div');
  zoom.className = 's2p-zoom';
  const img = document.createElement('img');
  img.dataset.testid = 'frame-image';
  img.draggable = false;
  const NS = 'http://www.w3.org/2000/svg';
  const svg = document.createElementNS(NS, 'svg');
  svg.setAttribute('class', 's2p-overlay');
  const base = document.createElementNS(NS, 'polygon');
  base.setAttribute('class', 's2p-base'); base.dataset.testid = 'box-base';
  const handle = document.createElementNS(NS, 'circle');
  handle.setAttribute('class', 's2p-handle'); handle.dataset.testid = 'box-handle';
  svg.append(base, handle);
  zoom.append(img, svg);
  stage.append(zoom);
  const strip = document.createElement('div');
  strip.className = 's2p-thumbs';
  wrap.append(bar, stage, strip);
  el.appendChild(wrap);
  // zoom and pan: a CSS transform of the picture and its overlay (clicks stay exact: the
  // pixel is computed from the transformed element's box)
  let s = 1, tx = 0, ty = 0;
  const apply = () => { zoom.style.transform = `translate(${tx}px, ${ty}px) scale(${s})`; };
  const zoomAt = (f, cx, cy) => {
    const r = stage.getBoundingClientRect();
    const px = cx - r.left, py = cy - r.top;
    const ns = Math.min(16, Math.max(1, s * f));
    tx = px - (px - tx) * ns / s; ty = py - (py - ty) * ns / s; s = ns;
    if (s === 1) { tx = 0; ty = 0; }
    apply();
  };
  const fit = () => { s = 1; tx = 0; ty = 0; apply(); };
  stage.addEventListener('wheel', (e) => {
    e.preventDefault(); zoomAt(e.deltaY < 0 ? 1.25 : 0.8, e.clientX, e.clientY);
  }, {passive: false});
  tools.querySelector('[data-testid=fit]').addEventListener('click', fit);
  const filt = () => {
    const b = tools.querySelector('[data-testid=brightness]').value;
    const c = tools.querySelector('[data-testid=contrast]').value;
    img.style.filter = `brightness(${b / 100}) contrast(${c / 100})`;
  };
  tools.addEventListener('input', filt);
  const onkey = (e) => {
    const t = (e.composedPath && e.composedPath()[0]) || e.target;
    if (t.tagName === 'INPUT' || t.tagName === 'TEXTAREA' || e.ctrlKey || e.altKey || e.metaKey) return;
    const r = stage.getBoundingClientRect();
    if (e.key === '0') fit();
    else if (e.key === '+' || e.key === '=') zoomAt(1.25, r.left + r.width / 2, r.top + r.height / 2);
    else if (e.key === '-') zoomAt(0.8, r.left + r.width / 2, r.top + r.height / 2);
    else return;
    e.preventDefault();
  };
  window.addEventListener('keydown', onkey);
  const thumbs = (v) => {  // the other cameras, small: a click shows one large
    strip.replaceChildren(...(v.thumbs || []).map((t) => {
      const box = document.createElement('figure');
      const im = document.createElement('img');
      im.src = t.src; im.dataset.testid = 'thumb'; im.dataset.camera = t.camera; im.draggable = false;
      im.title = `camera ${t.camera}: click to show it large (k: the next camera)`;
      im.addEventListener('click', () => model.send({large: t.camera}));
      const c = document.createElement('figcaption'); c.textContent = t.camera;
      box.append(im, c);
      return box;
    }));
  };
  const drawBox = (v) => {
    svg.setAttribute('viewBox', `0 0 ${v.width} ${v.height}`);
    const b = v.box;
    base.setAttribute('points', b ? b.base.map((p) => p.join(',')).join(' ') : '');
    base.style.display = handle.style.display = b ? '' : 'none';
    base.removeAttribute('transform');
    if (b) { handle.setAttribute('cx', b.handle[0]); handle.setAttribute('cy', b.handle[1]);
             handle.setAttribute('r', Math.max(4, v.width / 180)); }
  };
  const draw = () => {
    const v = model.get('view') || {};
    if (!v.src) { cap.textContent = 'loading the camera picture...'; return; }
    img.onload = () => {  // the attributes change with the picture, never before it is shown
      img.dataset.frame = v.frame; img.dataset.camera = v.camera;
      img.dataset.width = v.width; img.dataset.height = v.height;
      cap.textContent = v.caption;
      cap.classList.toggle('warn', !!v.note);
      drawBox(v);
      if (v.thumbs) thumbs(v);  // none during a playback: the small pictures stay
      // when each frame's picture was shown (benches/bench_app.py reads it)
      (window.__s2p_shown = window.__s2p_shown || {})[v.frame] = performance.now();
    };
    img.src = v.src;
  };
  draw();
  model.on('change:view', draw);
  const pixel = (e) => {
    const r = img.getBoundingClientRect();
    const w = Number(img.dataset.width), h = Number(img.dataset.height);
    if (!w || !h || r.width <= 0 || r.height <= 0) return null;
    return [(e.clientX - r.left) / r.width * w, (e.clientY - r.top) / r.height * h];
  };
  // a press: on the box's base moves it, on the handle turns it, elsewhere pans (zoomed in);
  // a press and release within 4 px is a click (a keyframe there)
  let down = null;
  stage.addEventListener('pointerdown', (e) => {
    if (e.button !== 0) return;
    const t = e.target;
    const mode = t === base ? 'move' : t === handle ? 'rotate' : 'pan';
    down = {x: e.clientX, y: e.clientY, tx, ty, mode, uv: pixel(e)};
    stage.setPointerCapture(e.pointerId);
  });
  stage.addEventListener('pointermove', (e) => {
    if (!down) return;
    if (down.mode === 'pan' && s > 1) { tx = down.tx + e.clientX - down.x; ty = down.ty + e.clientY - down.y; apply(); }
    if (down.mode === 'move') {
      const uv = pixel(e);
      if (uv && down.uv) base.setAttribute('transform', `translate(${uv[0] - down.uv[0]}, ${uv[1] - down.uv[1]})`);
    }
  });
  stage.addEventListener('pointerup', (e) => {
    if (!down) return;
    const d = down; down = null;
    const moved = Math.hypot(e.clientX - d.x, e.clientY - d.y) > 4;
    const uv = pixel(e);
    const at = {camera: img.dataset.camera, frame: Number(img.dataset.frame)};
    if (!uv) return;
    if (!moved) { model.send({click: uv, ...at}); return; }
    if (d.mode === 'move' && d.uv) model.send({drag: [d.uv, uv], ...at});
    else if (d.mode === 'rotate') model.send({rotate_to: uv, ...at});
  });
  return () => window.removeEventListener('keydown', onkey);
}
export default { render };
"""

_CSS = """
.s2p-frame { width: 100%; }
.s2p-frame-bar { display: flex; align-items: center; gap: 6px; }
.s2p-stage { width: 100%; overflow: hidden; position: relative; touch-action: none; }
.s2p-zoom { transform-origin: 0 0; position: relative; }
.s2p-zoom img { width: 100%; height: auto; display: block; cursor: crosshair;
                image-rendering: auto; user-select: none; }
.s2p-overlay { position: absolute; left: 0; top: 0; width: 100%; height: 100%; pointer-events: none; }
.s2p-base { fill: rgba(255, 230, 0, 0.18); stroke: #ffe600; stroke-width: 1; stroke-dasharray: 4 3;
            pointer-events: auto; cursor: move; vector-effect: non-scaling-stroke; }
.s2p-handle { fill: #ffe600; stroke: #333; pointer-events: auto; cursor: grab; }
.s2p-frame-cap { flex: 1 1 auto; font: 12px/1.4 system-ui, sans-serif; color: #333; height: 1.4em;
                 overflow: hidden; white-space: nowrap; text-overflow: ellipsis; }
.s2p-frame-cap.warn { color: #b00; }
.s2p-tools { font: 12px system-ui, sans-serif; white-space: nowrap; }
.s2p-tools input[type=range] { width: 60px; vertical-align: middle; }
.s2p-thumbs { display: flex; gap: 4px; margin-top: 4px; }
.s2p-thumbs figure { margin: 0; flex: 1 1 0; max-width: 25%; }
.s2p-thumbs img { width: 100%; display: block; cursor: pointer; }
.s2p-thumbs figcaption { font: 11px system-ui, sans-serif; color: #555; }
"""


class FrameView(anywidget.AnyWidget):
    """The widget; ``show`` a picture."""

    _esm = _ESM
    _css = _CSS
    view = traitlets.Dict({}).tag(sync=True)

    def show(self, camera: str, frame: int, jpeg: bytes, width: int, height: int,
             note: str = "", thumbs: dict[str, bytes] | None = None, box: dict | None = None,
             extra: str = "") -> None:
        """Show ``jpeg`` (camera ``camera``'s picture of ``frame``, ``width`` x ``height``
        image pixels) with ``thumbs`` (camera -> small JPEG of the other cameras; None: keep the
        ones shown); ``box``:
        the selected track's base {"base": [[u, v] x 4], "handle": [u, v]} (image pixels) to
        drag; ``extra``: more of the caption (the estimate's distance)."""
        caption = (f"camera {camera} · frame {frame}" + (f" · {extra}" if extra else "")
                   + (f" — {note}" if note else ""))
        self.view = {"src": _data_url(jpeg), "camera": camera, "frame": int(frame),
                     "width": int(width), "height": int(height), "caption": caption, "note": note,
                     "box": box,
                     "thumbs": None if thumbs is None else
                     [{"camera": c, "src": _data_url(j)} for c, j in thumbs.items()]}


def _data_url(jpeg: bytes) -> str:
    return "data:image/jpeg;base64," + base64.b64encode(jpeg).decode("ascii")
