"""The large camera view of the annotation page: an anywidget showing the server's picture of
the current frame (frame_image.py) in an ``<img>``. A click on it (not a drag) sends
{"click": [u, v], "camera": ..., "frame": ...}: the image pixel (x right, y down, pixel
centres at +0.5), computed from the element's size, so every click lands, repeated or not.

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
  const cap = document.createElement('div');
  cap.className = 's2p-frame-cap';
  cap.dataset.testid = 'frame-caption';
  const img = document.createElement('img');
  img.dataset.testid = 'frame-image';
  img.draggable = false;
  wrap.append(cap, img);
  el.appendChild(wrap);
  const draw = () => {
    const v = model.get('view') || {};
    if (!v.src) { cap.textContent = 'loading the camera picture...'; return; }
    img.onload = () => {  // the attributes change with the picture, never before it is shown
      img.dataset.frame = v.frame; img.dataset.camera = v.camera;
      img.dataset.width = v.width; img.dataset.height = v.height;
      cap.textContent = v.caption;
      cap.classList.toggle('warn', !!v.note);
      // when each frame's picture was shown (benches/bench_app.py reads it)
      (window.__s2p_shown = window.__s2p_shown || {})[v.frame] = performance.now();
    };
    img.src = v.src;
  };
  draw();
  model.on('change:view', draw);
  let down = null;
  img.addEventListener('pointerdown', (e) => { if (e.button === 0) down = [e.clientX, e.clientY]; });
  img.addEventListener('pointerup', (e) => {
    if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) { down = null; return; }
    down = null;
    const r = img.getBoundingClientRect();
    const w = Number(img.dataset.width), h = Number(img.dataset.height);
    if (!w || !h || r.width <= 0 || r.height <= 0) return;
    const u = (e.clientX - r.left) / r.width * w, v = (e.clientY - r.top) / r.height * h;
    model.send({click: [u, v], camera: img.dataset.camera, frame: Number(img.dataset.frame)});
  });
}
export default { render };
"""

_CSS = """
.s2p-frame { width: 100%; }
.s2p-frame img { width: 100%; height: auto; display: block; cursor: crosshair;
                 image-rendering: auto; user-select: none; }
.s2p-frame-cap { font: 12px/1.4 system-ui, sans-serif; color: #333; height: 1.4em;
                 overflow: hidden; white-space: nowrap; text-overflow: ellipsis; }
.s2p-frame-cap.warn { color: #b00; }
"""


class FrameView(anywidget.AnyWidget):
    """The widget; ``show`` a picture."""

    _esm = _ESM
    _css = _CSS
    view = traitlets.Dict({}).tag(sync=True)

    def show(self, camera: str, frame: int, jpeg: bytes, width: int, height: int,
             note: str = "") -> None:
        caption = f"camera {camera} · frame {frame}" + (f" — {note}" if note else "")
        self.view = {"src": "data:image/jpeg;base64," + base64.b64encode(jpeg).decode("ascii"),
                     "camera": camera, "frame": int(frame), "width": int(width),
                     "height": int(height), "caption": caption, "note": note}
