"""The annotation server process (``python -m annotate.app.server``, started by serve.py): the
marimo page (notebook.py) as an ASGI app behind the Guard (guard.py), served by uvicorn on the
loopback address only.

Arguments travel in the environment: S2P_ANNOTATE_ARGS (JSON: scene, run, cameras, native,
port) and S2P_ANNOTATE_TOKEN (the random token; not on the command line, where ``ps`` shows it
to every local user). SIGINT and SIGTERM stop it within a few seconds; on the way out every
open project is closed, so the edit lock is released.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

ARGS_ENV = "S2P_ANNOTATE_ARGS"
TOKEN_ENV = "S2P_ANNOTATE_TOKEN"
NOTEBOOK = Path(__file__).with_name("notebook.py")
SESSION_TTL = 5  # seconds marimo keeps a page's session after its tab is gone


# the log (SCENE/annotations/server.log): a timestamp on every line; uvicorn's warnings and
# errors, one line per websocket connection (guard.py) and per edit (controller.py)
LOG_CONFIG = {
    "version": 1, "disable_existing_loggers": False,
    "formatters": {"ts": {"format": "%(asctime)s %(levelname)s %(name)s: %(message)s"}},
    "handlers": {"out": {"class": "logging.StreamHandler", "formatter": "ts",
                         "stream": "ext://sys.stdout"}},
    "loggers": {"uvicorn": {"handlers": ["out"], "level": "WARNING", "propagate": False},
                "uvicorn.access": {"handlers": ["out"], "level": "WARNING", "propagate": False},
                "s2p.annotate": {"handlers": ["out"], "level": "INFO", "propagate": False}},
}
ASSET_PREFIX = "/s2p-viewer/"  # + the rerun-notebook version + /widget.js, /re_viewer_bg.wasm


def asset_url(port: int) -> str:
    """Where the page loads the viewer widget from: this server (behind the same Guard), so
    an SSH tunnel of this one port carries everything, and no second server listens."""
    from importlib.metadata import version

    return f"http://127.0.0.1:{port}{ASSET_PREFIX}{version('rerun-notebook')}/widget.js"


class ViewerAssets:
    """ASGI app: rerun-notebook's widget.js and re_viewer_bg.wasm under ASSET_PREFIX (the Wasm
    gzipped once into the viewer cache by ``prepare``, served plain until then); everything
    else goes to ``app``. (rerun-notebook's own "serve-local" server gzips the 50 MB Wasm at
    level 9 in every server process: 25 s of the first page load on a loaded machine.)"""

    def __init__(self, app):
        self.app = app

    @staticmethod
    def _files() -> dict[str, tuple]:
        import rerun_notebook

        return {"widget.js": (rerun_notebook.WIDGET_PATH, "text/javascript"),
                "re_viewer_bg.wasm": (rerun_notebook.WASM_PATH, "application/wasm")}

    async def __call__(self, scope, receive, send):
        path = scope.get("path", "")
        if scope["type"] != "http" or not path.startswith(ASSET_PREFIX):
            return await self.app(scope, receive, send)
        name = path.rsplit("/", 1)[-1]
        files = self._files()
        if name not in files:
            body = b"not found\n"
            await send({"type": "http.response.start", "status": 404,
                        "headers": [(b"content-length", str(len(body)).encode())]})
            await send({"type": "http.response.body", "body": body})
            return
        src, kind = files[name]
        gz = gz_path(src)
        headers = [(b"content-type", kind.encode()), (b"cache-control", b"max-age=86400")]
        if gz.exists():
            data = gz.read_bytes()
            headers.append((b"content-encoding", b"gzip"))
        else:
            data = src.read_bytes()
        headers.append((b"content-length", str(len(data)).encode()))
        await send({"type": "http.response.start", "status": 200, "headers": headers})
        await send({"type": "http.response.body", "body": data})


def gz_path(src: Path) -> Path:
    """The gzipped copy of a viewer asset in the cache (named by its size and mtime)."""
    import os

    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    st = src.stat()
    return Path(base) / "s2p" / "viewer-assets" / f"{src.name}-{st.st_size}-{st.st_mtime_ns}.gz"


def prepare_assets() -> None:
    """Gzip the Wasm into the cache once (level 6: a few seconds, once per installation)."""
    import gzip

    from seg2pose.io.atomic import atomic_write_bytes

    for src, _ in ViewerAssets._files().values():
        gz = gz_path(src)
        if gz.exists() or src.suffix != ".wasm":
            continue
        gz.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(gz, gzip.compress(src.read_bytes(), compresslevel=6))


def build_app(port: int, token: str):
    """marimo's app for notebook.py (with its own token check too) and the viewer's assets,
    behind the Guard."""
    import marimo

    from annotate.app.guard import Guard

    inner = (marimo.create_asgi_app(quiet=True, token=token, session_ttl=SESSION_TTL)
             .with_app(path="", root=str(NOTEBOOK)).build())
    return Guard(ViewerAssets(inner), port, token)


def main() -> None:
    import uvicorn

    args = json.loads(os.environ.get(ARGS_ENV) or "{}")
    token = os.environ.pop(TOKEN_ENV, "")
    if "port" not in args or not token:
        sys.exit(f"{ARGS_ENV} (with a port) and {TOKEN_ENV} must be set: start the app with "
                 "`s2p annotate SCENE`")
    # the viewer widget comes from this server (before anything imports rerun_notebook)
    os.environ["RERUN_NOTEBOOK_ASSET"] = asset_url(int(args["port"]))
    import threading

    threading.Thread(target=prepare_assets, daemon=True).start()
    server = uvicorn.Server(uvicorn.Config(
        build_app(int(args["port"]), token), host="127.0.0.1", port=int(args["port"]),
        log_level="warning", timeout_keep_alive=300, ws_ping_interval=1, ws_ping_timeout=60,
        timeout_graceful_shutdown=1, log_config=LOG_CONFIG))
    # uvicorn handles SIGINT / SIGTERM (graceful shutdown), then raises the signal again with
    # the handler it found: make that an exit that runs the ``finally`` below
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        server.run()
    finally:
        from annotate.app.controller import close_all

        close_all()


if __name__ == "__main__":
    main()
