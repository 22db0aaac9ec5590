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


def build_app(port: int, token: str):
    """marimo's app for notebook.py (with its own token check too) behind the Guard."""
    import marimo

    from annotate.app.guard import Guard

    inner = (marimo.create_asgi_app(quiet=True, token=token, session_ttl=SESSION_TTL)
             .with_app(path="", root=str(NOTEBOOK)).build())
    return Guard(inner, port, token)


def main() -> None:
    import uvicorn

    args = json.loads(os.environ.get(ARGS_ENV) or "{}")
    token = os.environ.pop(TOKEN_ENV, "")
    if "port" not in args or not token:
        sys.exit(f"{ARGS_ENV} (with a port) and {TOKEN_ENV} must be set: start the app with "
                 "`s2p annotate SCENE`")
    os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "serve-local")
    server = uvicorn.Server(uvicorn.Config(
        build_app(int(args["port"]), token), host="127.0.0.1", port=int(args["port"]),
        log_level="warning", timeout_keep_alive=300, ws_ping_interval=1, ws_ping_timeout=60,
        timeout_graceful_shutdown=1))
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
