"""The side panel of the annotation page: an anywidget whose HTML is rendered here from the
controller's ``panel()`` data. Its JavaScript sends {"action": NAME} for a button or a
shortcut key, {"heartbeat": 1} every few seconds (the page is alive), and listens to keys on
the window in the capture phase, so shortcuts work while the Rerun canvas has the focus
(and arrows step frames through the controller rather than the viewer's own time control).
"""

from __future__ import annotations

import html
import json

import anywidget
import traitlets

_ESM = r"""
function keyName(e) {
  const k = e.key.length === 1 ? e.key.toLowerCase() : e.key;
  return (e.ctrlKey || e.metaKey ? 'Ctrl+' : '') + (e.altKey ? 'Alt+' : '') +
         (e.shiftKey ? 'Shift+' : '') + (e.code && e.code.startsWith('Key') ? e.code.slice(3).toLowerCase() : k);
}
function render({ model, el }) {
  const box = document.createElement('div');
  box.className = 's2p-panel';
  el.appendChild(box);
  const draw = () => { box.innerHTML = model.get('html'); };
  draw();
  model.on('change:html', draw);
  box.addEventListener('click', (e) => {
    const b = e.target.closest('[data-action]');
    if (b) { e.preventDefault(); model.send({action: b.dataset.action}); }
  });
  box.addEventListener('change', (e) => {
    const t = e.target;
    if (t.dataset.prefix) { model.send({action: t.dataset.prefix + t.value}); }
    if (t.dataset.testid === 'goto') { t.blur(); }
  });
  // clicks on the viewer's canvas (not drags): the viewer reports a click only as a change of
  // its selection, so a second click on the same point says nothing; the server repeats the
  // last click when a canvas click at the same place brings no selection change (session.py).
  // Sent after two frames, when the viewer has reported the selection a click made.
  let down = null;
  const ondown = (e) => {
    const t = (e.composedPath && e.composedPath()[0]) || e.target;
    down = (t.tagName === 'CANVAS') ? [e.clientX, e.clientY] : null;
  };
  const onup = (e) => {
    if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) { down = null; return; }
    const at = down; down = null;
    const fr = box.querySelector('[data-testid=frame-number]');  // the frame clicked at
    const frame = fr ? parseInt(fr.textContent, 10) : null;
    requestAnimationFrame(() => requestAnimationFrame(() => setTimeout(
      () => model.send({canvas_click: at, frame: frame}), 150)));
  };
  window.addEventListener('pointerdown', ondown, true);
  window.addEventListener('pointerup', onup, true);
  const onkey = (e) => {
    const t = (e.composedPath && e.composedPath()[0]) || e.target;
    // typing into a visible form field of the panel is not a shortcut (the viewer's own
    // hidden text field, which has the focus after a click on the canvas, is)
    const field = (t.tagName === 'TEXTAREA' || t.tagName === 'SELECT' ||
                   (t.tagName === 'INPUT' && box.contains(t)));
    if (field) return;
    const name = model.get('shortcuts')[keyName(e)];
    if (!name) return;
    e.preventDefault(); e.stopImmediatePropagation();
    if (name === 'goto_frame') {  // the page's own action: type the frame, Enter goes there
      const f = box.querySelector('[data-testid=goto]');
      if (f) { f.focus(); f.select(); }
      return;
    }
    model.send({action: name});
  };
  window.addEventListener('keydown', onkey, true);
  // the tab's id survives reloads (sessionStorage is per tab): a reloaded tab keeps the edit lock
  let tab = sessionStorage.getItem('s2p-annotate-tab');
  if (!tab) {
    tab = (crypto.randomUUID ? crypto.randomUUID() : String(Math.random()).slice(2));
    sessionStorage.setItem('s2p-annotate-tab', tab);
  }
  // the WebGL renderer: in software (SwiftShader, llvmpipe) the 3D viewer starts hidden
  let renderer = '';
  try {
    const g = document.createElement('canvas').getContext('webgl2')
      || document.createElement('canvas').getContext('webgl');
    const d = g && g.getExtension('WEBGL_debug_renderer_info');
    renderer = g ? String(g.getParameter(d ? d.UNMASKED_RENDERER_WEBGL : g.RENDERER)) : 'none';
  } catch (err) { renderer = 'unknown'; }
  model.send({hello: tab, renderer: renderer});
  // the Rerun viewer on/off (Shift+V; off at first under software rendering): its element is
  // hidden, since even a small viewer repaints for seconds there and holds up the page
  const canvases = (root, out) => {
    for (const e of root.querySelectorAll('*')) {
      if (e.tagName === 'CANVAS') out.push(e);
      if (e.shadowRoot) canvases(e.shadowRoot, out);
    }
    return out;
  };
  const applyViewer = () => {
    const found = canvases(document, []);
    for (const c of found) {
      const host = c.getRootNode().host || c.parentElement;
      if (host) host.style.display = model.get('hide_viewer') ? 'none' : '';
    }
    return found.length > 0;
  };
  model.on('change:hide_viewer', applyViewer);
  let tries = 0;
  const seek = setInterval(() => { if (applyViewer() || ++tries > 240) clearInterval(seek); }, 250);
  const beat = setInterval(() => model.send({heartbeat: 1}), 4000);
  return () => { window.removeEventListener('keydown', onkey, true); clearInterval(beat); clearInterval(seek);
                 window.removeEventListener('pointerdown', ondown, true);
                 window.removeEventListener('pointerup', onup, true); };
}
export default { render };
"""

_CSS = """
.s2p-panel { font: 13px/1.35 system-ui, sans-serif; }
.s2p-panel h4 { margin: 8px 0 4px; font-size: 13px; }
.s2p-panel table { border-collapse: collapse; width: 100%; }
.s2p-panel td, .s2p-panel th { padding: 1px 5px; text-align: left; border-bottom: 1px solid #ddd; }
.s2p-panel tr.sel { background: #fff3b0; }
.s2p-panel tr[data-action] { cursor: pointer; }
.s2p-panel button { margin: 1px; padding: 1px 6px; font-size: 12px; }
.s2p-panel kbd { font-size: 11px; color: #555; border: 1px solid #bbb; border-radius: 3px;
                 padding: 0 3px; margin-left: 3px; }
.s2p-panel .msg { padding: 3px 6px; background: #eef; border-radius: 4px; height: 2.7em;
                 overflow: hidden; }
.s2p-panel td.warn { max-width: 16em; }
.s2p-panel td.warn summary { white-space: nowrap; overflow: hidden; text-overflow: ellipsis;
                             cursor: pointer; }
.s2p-panel .ro { padding: 3px 6px; background: #fdd; border-radius: 4px; font-weight: bold; }
.s2p-panel .warn { color: #b00; }
"""


class Panel(anywidget.AnyWidget):
    """The panel widget; set ``html`` (see ``render``) and ``shortcuts`` (key -> action)."""

    _esm = _ESM
    _css = _CSS
    html = traitlets.Unicode("").tag(sync=True)
    shortcuts = traitlets.Dict({}).tag(sync=True)
    hide_viewer = traitlets.Bool(True).tag(sync=True)  # until the page says it renders with a GPU


def _e(x) -> str:
    return html.escape(str(x))


def _button(a: dict, disabled: bool = False) -> str:
    return (f'<button data-action="{_e(a["name"])}" title="{_e(a["key"])}"'
            f'{" disabled" if disabled else ""}>{_e(a["label"])}<kbd>{_e(a["key"])}</kbd></button>')


def _warnings(w: list[str]) -> str:
    """A track's warnings on one line (how many, the first), the rest on demand."""
    if not w:
        return ""
    head = f"{len(w)}: {w[0]}" if len(w) > 1 else w[0]
    if len(w) == 1:
        return f'<span title="{_e(head)}">{_e(head)}</span>'
    return (f'<details><summary title="{_e("; ".join(w))}">{_e(head)}</summary>'
            + "".join(f"<div>{_e(x)}</div>" for x in w[1:]) + "</details>")


def _link_rows(rows: list[dict], testid: str) -> str:
    """Rows {"track", "frame", "text"} as a table whose rows go to their track and frame."""
    body = "".join(f'<tr data-action="look:{int(r["track"])}:{int(r["frame"])}" '
                   f'data-track="{int(r["track"])}" data-frame="{int(r["frame"])}">'
                   f'<td>{int(r["track"])}</td><td>{int(r["frame"])}</td><td>{_e(r["text"])}</td></tr>'
                   for r in rows)
    return (f'<table data-testid="{testid}"><tr><th>track</th><th>frame</th><th></th></tr>'
            f'{body}</table>')


def _review(p: dict) -> list[str]:
    """The selected track's box size, provenance and distance to its reference; the review
    queue; the lists others provide."""
    out = []
    info = p.get("info")
    if info is not None:
        size = ",".join(f"{v:.2f}" for v in info["size"])
        src = ", ".join(f"{n} {k}" for k, n in sorted(info["sources"].items())) or "no rows"
        rev = ", ".join(f"{a}..{b}" for a, b in info["reviewed"]) or "none"
        dist = ("–" if info["distance"] is None else f'{info["distance"]:.2f} m')
        out.append(f'<div>box l,w,h <input data-testid="size" data-prefix="set_size:" '
                   f'value="{size}" style="width:9em"> m <kbd>l j h</kbd> · from the '
                   f'{_e(info["reference"])} here: <b data-testid="distance">{dist}</b></div>'
                   f'<div data-testid="provenance">rows: {_e(src)} · reviewed: '
                   f'<span data-testid="reviewed">{_e(rev)}</span></div>')
    if p.get("playing") is not None:
        out.append(f'<div data-testid="playing">playing to frame {p["playing"]} (any key stops)</div>')
    looks = [{"track": r["track"], "frame": r["frame"],
              "text": f'{r["score"]:.2f} m · frames {r["first"]}..{r["last"]}'} for r in p["review"]]
    out.append('<h4>to review (worst first) <kbd>g</kbd></h4>'
               + (_link_rows(looks, "review-queue") if looks else
                  '<div data-testid="review-queue">nothing unchecked</div>'))
    queue = p.get("queue") or []  # annotate.suggest's road users to annotate next (u)
    if queue:
        body = "".join(f'<tr data-action="goto:{int(q["frames"][0])}" data-frame="{int(q["frames"][0])}">'
                       f'<td>{int(q["track"])}</td><td>{_e(q["cls"])}</td><td>{int(q["frames"][0])}</td>'
                       f'<td>{_e(q["why"])}</td></tr>' for q in queue if q.get("frames"))
        out.append('<h4>to annotate next <kbd>u</kbd></h4><table data-testid="annotate-queue"><tr>'
                   f'<th>run track</th><th>class</th><th>frame</th><th></th></tr>{body}</table>')
    job = p.get("train_job")
    if job:
        out.append(f'<div data-testid="train-job">training: {_e(job)}</div>')
    for title, rows in (p.get("lists") or {}).items():
        out.append(f"<h4>{_e(title)}</h4>" + _link_rows(
            [{"track": r.get("track", 0), "frame": r.get("frame", 0), "text": r.get("text", "")}
             for r in rows], "list"))
    return out


def render(p: dict) -> str:
    """The panel's HTML from ``Controller.panel()`` data."""
    out = []
    if p["read_only"]:
        out.append(f'<div class="ro" data-testid="read-only">{_e(p["read_only"])}</div>')
    sel = p["selected"]
    here = f" — track {sel}: {p['here']}" if sel is not None else " — no track selected"
    out.append(f'<div data-testid="frame">scene <b>{_e(p["scene"])}</b> · frame '
               f'<b data-testid="frame-number">{p["frame"]}</b> of {p["frame_range"][0]}..'
               f'{p["frame_range"][1]}{_e(here)}</div>')
    out.append(f'<div>viewer: <span data-testid="viewer-state">{_e(p["viewer"])}</span></div>')
    if p.get("no_video"):
        out.append(f'<div class="warn" data-testid="no-video">no video for frame {p["frame"]} in '
                   f'{_e(", ".join(p["no_video"]))}: the camera view shows no picture</div>')
    out.append(f'<div class="msg" data-testid="message" title="{_e(p["message"])}">'
               f'{_e(p["message"])}</div>')
    lc = p["last_click"]
    if lc:
        out.append(f'<div data-testid="last-click" data-n="{lc["n"]}" data-camera="{_e(lc["camera"])}"'
                   f' data-uv="{_e(json.dumps(lc["uv"]))}">last click #{lc["n"]}: camera {_e(lc["camera"])}, '
                   f'pixel {_e(lc["uv"])}</div>')
    out.append(f'<div>click mode <b data-testid="click-mode">{_e(p["click_mode"])}</b>: '
               f'{_e(p["click_help"])}</div>')
    opts = "".join(f'<option{" selected" if c == p["new_class"] else ""}>{_e(c)}</option>'
                   for c in p["classes"])
    out.append(f'<div>go to frame <input type="number" data-testid="goto" data-prefix="goto:" '
               f'min="{p["frame_range"][0]}" max="{p["frame_range"][1]}" style="width:5em">'
               '<kbd>f</kbd></div>')
    out.append(f'<div>new tracks: <select data-prefix="class:">{opts}</select> · accept every '
               f'<input type="number" min="1" value="{p["every"]}" data-prefix="every:" '
               f'style="width:4em"> frames</div>')
    # track list
    rows = ["<tr><th>id</th><th>class</th><th>keyframes</th><th>span</th><th>interp.</th>"
            "<th>warnings</th></tr>"]
    for t in p["tracks"]:
        span = "–" if t["span"] is None else f'{t["span"][0]}..{t["span"][1]}'
        rows.append(f'<tr data-action="select:{t["id"]}" data-track="{t["id"]}"'
                    f'{" class=sel" if t["selected"] else ""}><td>{t["id"]}</td><td>{_e(t["cls"])}'
                    f'</td><td>{t["keyframes"]}</td><td>{span}</td><td>{_e(t["interp"])}</td>'
                    f'<td class="warn">{_warnings(t["warnings"])}</td></tr>')
    out.append(f'<h4>tracks</h4><table data-testid="tracks">{"".join(rows)}</table>')
    if sel is not None:
        rows = ["<tr><th>frame</th><th>x (m)</th><th>y (m)</th><th>heading (°)</th><th></th>"
                "<th>flags</th></tr>"]
        for k in p["keyframes"]:
            rows.append(f'<tr data-action="goto:{k["frame"]}" data-frame="{k["frame"]}"'
                        f'{" class=sel" if k["current"] else ""}><td>{k["frame"]}</td>'
                        f'<td>{k["x"]:.2f}</td><td>{k["y"]:.2f}</td><td>{k["heading_deg"]:.1f}</td>'
                        f'<td data-testid="heading-mode">{k["heading_mode"]}</td>'
                        f'<td>{_e(", ".join(k["flags"]))}</td></tr>')
        out.append(f'<h4>keyframes of track {sel}</h4><table data-testid="keyframes">'
                   f'{"".join(rows)}</table>')
    out += _review(p)
    groups: dict[str, list[str]] = {}
    ro = bool(p["read_only"])
    classes = p["classes"]
    for a in p["actions"]:
        if a["name"].startswith("class_key:"):  # one button per class of the scene, named
            i = int(a["name"].split(":")[1])
            if i > len(classes):
                continue
            a = {**a, "label": classes[i - 1]}
        edit = a["group"] not in ("time",) and a["name"] not in ("next_track", "prev_track",
                                                                 "click_mode")
        groups.setdefault(a["group"], []).append(_button(a, disabled=ro and edit))
    for g, bs in groups.items():
        out.append(f'<h4>{_e(g)}</h4><div>{"".join(bs)}</div>')
    return "".join(out)
