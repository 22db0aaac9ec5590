"""The calibration page's server: a small Starlette app (calib_page.py's document, the server's
pictures, a JSON API over calib_state.PageState) behind the annotation app's Guard (guard.py:
a random token per start, Host and Origin checked), served by uvicorn on the loopback address
in the command's own process.

Why not the annotation app's marimo page: this page has no notebook state, no Rerun viewer and
no cells; it is two images, a table and five buttons. marimo's app would add its kernel, its
websocket protocol and several seconds of start-up for nothing the page uses; the pictures are
made on the server the same way (no GPU needed) and the gate is the same class.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from annotate.app.calib_state import PageArgs, PageState
from annotate.app.guard import TOKEN_PARAM, Guard, new_token
from seg2pose.core.errors import InputError, S2PError

__all__ = ["PageArgs", "build_app", "open_state", "run_page"]

JPEG_QUALITY = 90


def open_state(args: PageArgs):
    """(PageState, scene or None): frames and sizes from SCENE_OR_VIDEO (or --image-size), the
    journal beside the output (``<out stem>.points.jsonl``) or in the scene
    (``calibrations/points.jsonl``)."""
    from seg2pose.io.scene import SCENE_FILE, load_scene
    from seg2pose.io.video import FrameReader, camera_reader

    scene = None
    frames: dict = {}
    sizes: dict = {}
    src = args.source
    if src is not None and (src / SCENE_FILE).exists():
        scene = load_scene(src)
        cams = args.cameras or list(scene.cameras)
        for c in cams:
            if c not in scene.cameras:
                raise InputError(f"no camera {c!r} in the scene (it has {sorted(scene.cameras)})",
                                 field="camera")
            sizes[c] = (scene.cameras[c].width, scene.cameras[c].height)
            if scene.video_path(c) is not None:
                frames[c] = next(iter(camera_reader(scene, c).frames()), (0, None))[1]
    else:
        cams = args.cameras or ["c0"]
        if src is not None:
            if not src.exists():
                raise InputError("not found (expected a scene folder, a video or an image folder)", file=src)
            r = FrameReader(src)
            w, h, _ = r.header()
            im = next(iter(r.frames()), (0, None))[1]
            for c in cams:
                sizes[c], frames[c] = (w, h), im
    for c in cams:
        if c in args.sizes or "*" in args.sizes:
            sizes[c] = args.sizes.get(c, args.sizes.get("*"))
        if c not in sizes:
            raise InputError(f"no image size for camera {c!r}: give a video, a scene or --image-size",
                             field="image_size")
    if args.out is not None:
        journal = args.out.with_name(f"{args.out.stem}.points.jsonl")
    elif scene is not None:
        journal = scene.root / "calibrations" / "points.jsonl"
    else:
        raise InputError("give -o calib.json (where the result and the clicked points go)", field="out")
    if args.aerial is None and args.survey is None:
        raise InputError("the page needs --aerial IMAGE or --survey points.csv", field="aerial")
    return PageState(args, journal, sizes, frames), scene


def _picture(frame: np.ndarray | None, size: tuple[int, int]) -> bytes:
    import cv2

    if frame is None:
        frame = np.full((size[1], size[0], 3), 90, np.uint8)
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return buf.tobytes()


def build_app(state: PageState, scene, port: int, token: str):
    """The page's ASGI app behind the Guard."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import HTMLResponse, JSONResponse, Response
    from starlette.routing import Route

    from annotate.app.calib_page import PAGE

    def view() -> dict:
        return {"cameras": {c: list(s) for c, s in state.sizes.items()}, "pairs": state.pairs(),
                "survey": [{"name": n, "x": float(p[0]), "y": float(p[1]),
                            "z": None if np.isnan(p[2]) else float(p[2])}
                           for n, p in zip(state.survey_names, state.survey, strict=True)],
                "aerial": state.A is not None, "note": state.log.note,
                "solved": sorted(state.pictures)}

    def guarded(fn):
        async def endpoint(request: Request):
            try:
                return await fn(request)
            except S2PError as e:  # bad input: one line for the page to show
                return JSONResponse({"error": str(e)}, status_code=400)
        return endpoint

    async def page(request: Request):
        return HTMLResponse(PAGE, headers={"cache-control": "no-store"})

    async def get_state(request: Request):
        return JSONResponse(view())

    async def frame(request: Request):
        c = request.path_params["camera"]
        if c not in state.sizes:
            return Response("no such camera\n", status_code=404)
        return Response(_picture(state.frames.get(c), state.sizes[c]), media_type="image/jpeg")

    async def cost(request: Request):
        c = request.path_params["camera"]
        if c not in state.pictures:
            return Response("not solved\n", status_code=404)
        return Response(state.pictures[c], media_type="image/png")

    async def aerial(request: Request):
        if state.args.aerial is None:
            return Response("no aerial image\n", status_code=404)
        kind = "image/png" if state.args.aerial.suffix.lower() == ".png" else "image/jpeg"
        return Response(Path(state.args.aerial).read_bytes(), media_type=kind)

    async def body(request: Request) -> dict:
        try:
            d = json.loads(await request.body() or b"{}")
        except ValueError:
            raise InputError("the request is not JSON") from None
        if not isinstance(d, dict):
            raise InputError("expected a JSON object")
        return d

    def num(d: dict, k: str, optional: bool = False):
        v = d.get(k)
        if v is None and optional:
            return None
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise InputError(f"{k} must be a number", field=k)
        return float(v)

    async def pair(request: Request):
        d = await body(request)
        state.add_pair(str(d.get("camera")), num(d, "u"), num(d, "v"), num(d, "ax", True),
                       num(d, "ay", True), d.get("survey"), num(d, "z", True))
        return JSONResponse(view())

    async def undo(request: Request):
        state.undo()
        return JSONResponse(view())

    async def solve(request: Request):
        import anyio

        text = await anyio.to_thread.run_sync(state.solve)
        return JSONResponse({"report": text, "state": view()})

    async def save(request: Request):
        return JSONResponse({"lines": state.save(scene)})

    routes = [Route("/", page), Route("/api/state", guarded(get_state)),
              Route("/img/frame/{camera}", frame), Route("/img/cost/{camera}", cost),
              Route("/img/aerial", aerial),
              Route("/api/pair", guarded(pair), methods=["POST"]),
              Route("/api/undo", guarded(undo), methods=["POST"]),
              Route("/api/solve", guarded(solve), methods=["POST"]),
              Route("/api/save", guarded(save), methods=["POST"])]
    return Guard(Starlette(routes=routes), port, token, command="s2p calibrate-camera")


def run_page(args: PageArgs, browser: bool = True, echo=print) -> None:
    """``s2p calibrate-camera ... --aerial/--survey``: open the state, serve the page until
    Ctrl-C, then release the journal. The outputs a Save writes (calib.json and the files
    beside it, or the scene's scene.json) are locked from the start: another writer of them
    is refused while the page is open, not only during a Save."""
    import uvicorn

    from annotate.app.serve import free_port
    from seg2pose.io.atomic import holding
    from seg2pose.io.calib_files import output_names
    from seg2pose.io.scene import SCENE_FILE

    state, scene = open_state(args)
    held = (list(output_names(args.out, list(state.sizes)).values()) if args.out is not None
            else [scene.root / SCENE_FILE])
    try:
        with holding(*held):
            _serve(state, scene, args, browser, echo, free_port, uvicorn)
    finally:
        state.close()


def _serve(state: PageState, scene, args: PageArgs, browser: bool, echo, free_port, uvicorn) -> None:
    """Serve the page until Ctrl-C."""
    import socket

    port = args.port or free_port()
    with socket.socket() as sock:
        if sock.connect_ex(("127.0.0.1", port)) == 0:
            raise S2PError(f"port {port} is in use; choose another with --port")
    token = new_token()
    url = f"http://127.0.0.1:{port}/?{TOKEN_PARAM}={token}"
    n = len(state.pairs())
    echo(f"calibration page at {url}\n  ({n} pairs from {state.log.path}; only this machine can "
         f"reach it, from another one use an SSH tunnel: ssh -N -L {port}:127.0.0.1:{port} "
         "USER@THIS-HOST. Ctrl-C stops it.)")
    if browser:
        import webbrowser

        webbrowser.open(url)
    server = uvicorn.Server(uvicorn.Config(build_app(state, scene, port, token), host="127.0.0.1",
                                           port=port, log_level="warning"))
    try:
        server.run()
    except KeyboardInterrupt:  # Ctrl-C is how the page is stopped (uvicorn raises it again once shut down)
        echo("calibration page stopped")
