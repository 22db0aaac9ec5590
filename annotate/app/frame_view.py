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
  const strip = document.createElement('div');
  strip.className = 's2p-thumbs';
  wrap.append(cap, img, strip);
  el.appendChild(wrap);
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
  const draw = () => {
    const v = model.get('view') || {};
    if (!v.src) { cap.textContent = 'loading the camera picture...'; return; }
    img.onload = () => {  // the attributes change with the picture, never before it is shown
      img.dataset.frame = v.frame; img.dataset.camera = v.camera;
      img.dataset.width = v.width; img.dataset.height = v.height;
      cap.textContent = v.caption;
      cap.classList.toggle('warn', !!v.note);
      thumbs(v);
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
             note: str = "", thumbs: dict[str, bytes] | None = None) -> None:
        """Show ``jpeg`` (camera ``camera``'s picture of ``frame``, ``width`` x ``height``
        image pixels) with ``thumbs`` (camera -> small JPEG of the other cameras)."""
        caption = f"camera {camera} · frame {frame}" + (f" — {note}" if note else "")
        self.view = {"src": _data_url(jpeg), "camera": camera, "frame": int(frame),
                     "width": int(width), "height": int(height), "caption": caption, "note": note,
                     "thumbs": [{"camera": c, "src": _data_url(j)} for c, j in (thumbs or {}).items()]}


def _data_url(jpeg: bytes) -> str:
    return "data:image/jpeg;base64," + base64.b64encode(jpeg).decode("ascii")
