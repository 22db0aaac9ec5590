"""Kill s2p commands at random moments and classify what they leave under the outputs' names:
``absent``, ``old`` (the complete previous outputs), ``new`` (the complete new ones) or
``mixed`` (anything else: a partial or merged output, or a set of outputs of which some are
old and some new). Used by tests/system/test_kill.py (4-10 kills a command) and
benches/bench_faults.py (many).

The commands run in processes forked from one Python that has imported s2p already
(``Zygote``): a kill costs the command's own time, not the second or two a new interpreter
needs to import the project. What a command writes and how it is killed (SIGKILL, nothing
flushed, no handler run) is the same as for a command started from the shell."""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
S2P = [sys.executable, "-c", "from seg2pose.cli import main; main()"]


def snapshot(path: Path) -> dict | None:
    """The content of an output: None when absent; {relative path: bytes} of its files
    (a file output: {'': bytes}). run.json's creation time and ids.json's times are left out
    (they differ between two runs of the same command). Hidden siblings are not part of it."""
    if not path.exists():
        return None
    if path.is_file():
        return {"": path.read_bytes()}
    out = {}
    for p in sorted(path.rglob("*")):
        if p.is_file():
            data = p.read_bytes()
            if p.name == "run.json":
                d = json.loads(data)
                d.pop("created", None)
                data = json.dumps(d, sort_keys=True).encode()
            elif p.name == "ids.json":  # masks/ids.json: when each camera's ids were made
                d = json.loads(data)
                for e in d.get("cameras", {}).values():
                    e.pop("made", None)
                data = json.dumps(d, sort_keys=True).encode()
            out[str(p.relative_to(path))] = data
    return out


def classify(state: dict | None, old: dict | None, new: dict) -> str:
    if state is None:
        return "absent"
    if state == new:
        return "new"
    if state == old:
        return "old"
    return "mixed"



_ZYGOTE = r"""
import json, os, sys, traceback
sys.argv = ["s2p"]
import numpy, cv2                      # what every command imports, loaded once
cv2.setNumThreads(1)  # tiny frames: a thread pool per forked command costs more than it saves
import seg2pose.cli, seg2pose.video.video_scene, seg2pose.method.pipeline, seg2pose.batch.steps
import seg2pose.io.tacal, annotate, annotate.tanalyst_io, s2p_review.mcap_export
import seg2pose.batch.segments, seg2pose.eval.evaluate, annotate.export, s2p_review.annotated_mcap
import torch, seg2pose.method.net, seg2pose.method.sparse  # `run` imports torch (no thread starts on import)
import typer, typer._adapters, typer._coercion, typer.core, typer.main, pydantic, tqdm
import zoneinfo, fractions, email.utils, multiprocessing.synchronize, mcap_protobuf.writer
for m in ("Color", "CameraCalibration", "FrameTransform", "SceneUpdate", "PosesInFrame",
          "ImageAnnotations", "Point2", "PointsAnnotation", "RawImage"):
    __import__(f"foxglove_schemas_protobuf.{m}_pb2")
out = os.fdopen(1, "w", buffering=1)
out.write("ready\n")
for line in sys.stdin:
    argv, err = json.loads(line)
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            os.setpgid(0, 0)
            null = os.open(os.devnull, os.O_RDWR)
            os.dup2(null, 0)
            os.dup2(os.open(err, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), 2)
            os.dup2(2, 1)  # what it says too: batch reports a scene's failure in its table
            sys.argv = ["s2p", *argv]
            from seg2pose.cli import main
            main()
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        except BaseException:
            traceback.print_exc()
        finally:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
            finally:
                os._exit(code)
    out.write(f"{pid}\n")
    _, status = os.waitpid(pid, 0)
    out.write(f"{status}\n")
"""


class Zygote:
    """A Python that has imported s2p and forks one child per command. ``start(argv)`` ->
    the child's pid; ``wait(timeout)`` -> its exit code (negative: the signal that ended it),
    None while it runs. One command at a time."""

    def __init__(self):
        self.p = subprocess.Popen([sys.executable, "-c", _ZYGOTE], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, env=ENV, text=False)
        self.buf = b""
        self.err = Path(os.environ.get("TMPDIR", "/tmp")) / f"s2p-kill-{os.getpid()}-{id(self)}.err"
        if self._line(600) != "ready":  # imports done: a command's time is its own from here
            raise RuntimeError("the kill harness's Python did not start")

    def _line(self, timeout: float | None) -> str | None:
        end = None if timeout is None else time.perf_counter() + timeout
        while b"\n" not in self.buf:
            left = None if end is None else max(0.0, end - time.perf_counter())
            r, _, _ = select.select([self.p.stdout], [], [], left)
            if not r:
                return None
            chunk = os.read(self.p.stdout.fileno(), 4096)
            if not chunk:
                raise RuntimeError("the kill harness's Python ended")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return line.decode()

    def start(self, argv: list) -> int:
        self.p.stdin.write((json.dumps([[str(a) for a in argv], str(self.err)]) + "\n").encode())
        self.p.stdin.flush()
        return int(self._line(60))

    def wait(self, timeout: float | None = None) -> int | None:
        line = self._line(timeout)
        if line is None:
            return None
        status = int(line)
        return os.waitstatus_to_exitcode(status)

    def error_text(self) -> str:
        try:
            return self.err.read_text(errors="replace")[-2000:]
        except OSError:
            return ""

    def close(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self.p.stdin.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.p.wait(timeout=30)
        self.err.unlink(missing_ok=True)


_zygote: Zygote | None = None


def zygote() -> Zygote:
    global _zygote
    if _zygote is None or _zygote.p.poll() is not None:
        _zygote = Zygote()
        atexit.register(_zygote.close)  # its Python ends, and its error file goes
    return _zygote


def descendants(pid: int) -> list[int]:
    """The processes started by ``pid``, and by those, and so on (from /proc)."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                stat = Path(f"/proc/{d}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            children.setdefault(ppid, []).append(int(d))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def ray_workers_of(pids: list[int]) -> list[int]:
    """Processes whose environment names one of ``pids`` as their raylet (Ray's workers)."""
    want = {f"RAY_RAYLET_PID={p}".encode() for p in pids}
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                env = Path(f"/proc/{d}/environ").read_bytes().split(b"\0")
            except OSError:
                continue
            if want.intersection(env):
                out.append(int(d))
    return out


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in "ZX"
    except OSError:
        return False


def wait_gone(pids: list[int], timeout: float = 120.0) -> list[int]:
    """Wait until the processes ``pids`` have ended (zombies count as ended); those still
    running after ``timeout`` seconds."""
    end = time.perf_counter() + timeout
    while True:
        left = [p for p in pids if _running(p)]
        if not left or time.perf_counter() > end:
            return left
        time.sleep(0.1)


def _copy(src: Path | None, dst: Path) -> None:
    """Put ``src`` (a file, a folder, or None: nothing) at ``dst``."""
    if dst.is_dir() and not dst.is_symlink():
        shutil.rmtree(dst)
    elif dst.exists() or dst.is_symlink():
        dst.unlink()
    if src is None:
        return
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_dir():
        shutil.copytree(src, dst)
    else:
        shutil.copy2(src, dst)


@dataclass
class Case:
    """One command: ``argv`` writes the outputs ``outs`` (with --force where it needs it);
    ``olds`` are the complete outputs it replaces (files or folders copied into place before
    every kill; None: the output is absent before). ``state`` (default: the bytes of every
    output, ``snapshot``) is what is compared; ``resume`` (batch): after a kill, run again as
    a user would and say whether the result is the uninterrupted run's."""

    name: str
    argv: list
    outs: list
    olds: list
    state: Callable | None = None
    resume: bool = False
    rerun: list | None = None  # the re-run after a kill (default: argv without --force)
    tree: bool = False  # wait for the killed command's other processes (Ray's) to end
    stray: int = 0  # of those, still running 120 s after the kill
    new: object = None
    seconds: float = 1.0
    counts: dict = field(default_factory=lambda: {"absent": 0, "old": 0, "new": 0, "between": 0,
                                                  "mixed": 0, "finished": 0})
    mixed: list = field(default_factory=list)  # per mixed kill: each output's state, leftovers

    def __post_init__(self) -> None:
        self.outs = [Path(o) for o in self.outs]
        self.olds = [None if o is None else Path(o) for o in self.olds]

    @property
    def out(self) -> Path:
        return self.outs[0]

    def snap(self):
        if self.state is not None:
            return self.state(self)
        return [snapshot(o) for o in self.outs]

    def put_old(self) -> None:
        for o, old in zip(self.outs, self.olds):
            _copy(old, o)

    def old_state(self):
        if not hasattr(self, "_old"):
            self.put_old()
            self._old = self.snap()
        return self._old

    def run_fully(self) -> None:
        """Run to the end once: the reference new outputs and the command's duration."""
        self.old_state()
        self.put_old()
        z = zygote()
        t = time.perf_counter()
        z.start(self.argv)
        code = z.wait(600)
        self.seconds = time.perf_counter() - t
        if code != 0:
            raise RuntimeError(f"{self.name} failed ({code}): {z.error_text()}")
        self.new = self.snap()

    def classify(self) -> str:
        st, old, new = self.snap(), self._old, self.new
        if st == new:
            return "new"
        if st == old:
            return "old"
        if all(x is None for x in st):
            return "absent"
        if self.resume and all(x is None or x == o or x == n for x, o, n in zip(st, old, new)):
            return "between"  # some outputs done, each one whole: the re-run goes on from there
        return "mixed"

    def kill_once(self, rng: np.random.Generator, share: tuple[float, float] = (0.15, 1.05)) -> str:
        """Put the old outputs back, start the command, SIGKILL it after a random ``share`` of
        its usual duration (sometimes after it finished), classify the outputs. With ``resume``
        the command is then run again (without --force, as after a crash) and a re-run that
        fails or does not end with the uninterrupted run's outputs counts as ``mixed``. Then
        what the next writer does first is done (``finish_commits``); a mixed set that this
        makes the new one is also counted as ``finished``."""
        self.old_state()
        self.put_old()
        z = zygote()
        pid = z.start(self.argv)
        code = z.wait(rng.uniform(*share) * self.seconds)
        if code is None:
            tree = descendants(pid) if self.tree else []
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)
            z.wait()
            # Ray's processes (own process groups) end when the driver's raylet does; a task
            # may still finish its write meanwhile: the outputs are what they leave (a worker
            # forked just after the list was taken is found by its raylet's pid)
            if tree:
                tree += [p for p in ray_workers_of(tree) if p not in tree]
            self.stray += len(wait_gone(tree))
        kind = self.classify()
        if kind == "mixed":  # which outputs were what, and what lay beside them
            st = self.snap()
            self.mixed.append(([("new" if x == n else "old" if x == o else "absent" if x is None
                                 else "other") for x, o, n in zip(st, self._old, self.new)],
                               self.leftovers()))
        # what the next writer of any output does first: finish a set commit the killed one
        # recorded (so the old outputs put back for the next kill are not mixed with its builds)
        from seg2pose.io.atomic import finish_commits

        for o in self.outs:
            finish_commits(o)
        if kind == "mixed" and self.classify() == "new":
            self.counts["finished"] += 1
        if self.resume and kind != "mixed":
            z.start(self.rerun or [a for a in self.argv if a != "--force"])
            code = z.wait(600)
            if code != 0 or self.snap() != self.new:
                kind = "mixed"
                self.mixed.append(([f"the re-run after a {kind} kill: exit {code}",
                                    z.error_text()[-400:]], self.leftovers()))
        self.counts[kind] = self.counts.get(kind, 0) + 1
        return kind

    def leftovers(self) -> list[str]:
        """Hidden siblings of the outputs (temporary builds, locks, commit records)."""
        out = []
        for o in self.outs:
            if o.parent.is_dir():
                out += sorted(p.name for p in o.parent.iterdir() if p.name.startswith(f".{o.name}.")
                              or p.name.startswith(f"..{o.name}."))
        return out

    def live_leftovers(self) -> list[str]:
        """Leftovers that the next writer would not remove: partial outputs of processes
        that still run, or anything not named like a partial output, a commit record or a
        lock."""
        from seg2pose.core.locks import pid_alive
        from seg2pose.io.atomic_names import COMMIT_RECORD, owner

        out = []
        for n in self.leftovers():
            if n.endswith(".lock") and n[1:-5] in {o.name for o in self.outs}:
                continue
            own = owner(n)
            if own is not None and not any(pid_alive(p) for p in own[1]):
                continue
            m = COMMIT_RECORD.match(n)
            if m and not pid_alive(int(m.group("pid"))):
                continue
            out.append(n)
        return out


def build_cases(root: Path, frames: int = 40) -> list[Case]:
    """The five commands of issue 10 on small inputs under ``root``: s2p run, synth,
    convert-masks, import-utocs and export, each with an old output to replace."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from hostile_fixtures import write_scene, write_utocs
    from seg2pose.io.mask_formats import save_masks
    from seg2pose.io.mots import read_mots
    from seg2pose.io.utocs import import_utocs
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene
    from s2p_review.mcap_export import export_mcap
    from seg2pose.io.scene import load_scene

    root.mkdir(parents=True, exist_ok=True)
    scene = write_scene(root / "scene", frames=frames, users=4)
    other = write_scene(root / "other", frames=5, users=2)
    old = root / "old"
    old.mkdir()
    run_scene(other, old / "run", RunOptions(baseline=True, progress=False))
    run_scene(scene, root / "run", RunOptions(baseline=True, progress=False))
    generate_scene(old / "synth", SynthOptions(frames=3, seed=1, workers=1, progress=False))
    save_masks(old / "png", read_mots(other.masks_path("c0")), "png")
    import_utocs(write_utocs(root / "utocs-a", frames=2), old / "utocs", log=lambda *a: None)
    write_utocs(root / "utocs-b", frames=frames, images=True)
    export_mcap(load_scene(other.root), old / "run", old / "x.mcap")
    out = root / "out"
    out.mkdir()
    return [
        Case("run", ["run", scene.root, "-o", out / "run", "--baseline", "--force"], [out / "run"], [old / "run"]),
        Case("synth", ["synth", "-o", out / "synth", "--frames", "6", "--seed", "2", "--workers", "1", "--no-progress",
                       "--force"], [out / "synth"], [old / "synth"]),
        Case("convert-masks", ["convert-masks", scene.masks_path("c0"), "-o", out / "png", "--format", "png",
                               "--force"], [out / "png"], [old / "png"]),
        Case("import-utocs", ["import-utocs", root / "utocs-b", "-o", out / "utocs", "--force"], [out / "utocs"],
             [old / "utocs"]),
        Case("export", ["export", scene.root, "--run", root / "run", "-o", out / "x.mcap", "--force"],
             [out / "x.mcap"], [old / "x.mcap"]),
    ]


def _state_of(*paths: Path) -> Callable:
    return lambda case: [snapshot(p) for p in paths]


def _project_state(scene_root: Path) -> Callable:
    """The annotation project's tracks and history as a reader sees them (journal bytes hold
    times): None when there is no journal."""
    def state(case):
        from annotate import Project
        from annotate_fixtures import digest

        if not (scene_root / "annotations").exists():
            return [None]
        try:
            with Project.open(scene_root, read_only=True) as p:
                return [digest(p)]
        except Exception as e:  # noqa: BLE001 - a project that does not open is a broken output
            return [f"does not open: {e}"]
    return state


def build_writer_cases(root: Path, frames: int = 16) -> list[Case]:
    """The writing commands of issue 24 on tiny inputs under ``root``: masks-from-video,
    import-detections, track, new-scene, import-tacal, annotate export (gt + MCAP + layout +
    CSV as one set), annotate import-tanalyst, associate (masks/ as a unit), import-mcap --force
    into an existing scene folder (scene.json, ground points, run and journal as one set) and
    batch --serial (killed, then re-run)."""
    import contextlib as _cl

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from annotate import Project
    from review_fixtures import make_scene
    from seg2pose.cli.annotation import export_set
    from seg2pose.io.scene import load_scene
    from seg2pose.io.tacal import camera_to_tacal, write_tacal
    from seg2pose.video.video_scene import new_scene, scene_import_detections, scene_masks_from_video
    from video_fixtures import calibration, det, rle, write_folder

    root.mkdir(parents=True, exist_ok=True)
    old, out = root / "old", root / "out"
    old.mkdir()
    out.mkdir()
    cam = calibration(root)
    calib, ground = root / "calib.json", root / "ground.csv"
    write_folder(root / "frames", frames, [dict(id=1, x=10, y=60, w=10, h=24, vx=2, vy=0),
                                           dict(id=2, x=120, y=30, w=14, h=14, vx=-2, vy=1)])
    write_folder(root / "frames-b", 6, [dict(id=1, x=30, y=40, w=12, h=20, vx=1, vy=0)])
    quiet = dict(log=lambda *a: None)
    bg = ["--set", "min_area=40", "--set", "init_samples=8"]
    bgd = {"min_area": 40, "init_samples": 8}

    def video_scene(name: str) -> Path:
        new_scene(root / name, {"c0": root / "frames"}, calib, ground, fps=10, **quiet)
        return root / name

    # masks-from-video: replaces a detector's masks
    dets = root / "d.json"
    dets.write_text(json.dumps([det(f, 3, rle(20 + 3 * f, 40, 12, 10)) for f in range(frames)]))
    mfv = video_scene("mfv")
    scene_import_detections(mfv, "c0", dets, **quiet)
    shutil.copy2(mfv / "masks" / "c0.txt", old / "mfv-c0.txt")
    # import-detections: replaces background-subtraction masks
    imd = video_scene("imd")
    scene_masks_from_video(imd, bg=bgd, **quiet)
    shutil.copy2(imd / "masks" / "c0.txt", old / "imd-c0.txt")
    # track: masks without ids, tracked in place
    trk = video_scene("trk")
    scene_masks_from_video(trk, bg=bgd, track=False, classify=False, **quiet)
    shutil.copy2(trk / "masks" / "c0.txt", old / "trk-c0.txt")
    # new-scene and import-tacal: replace a scene folder made from other inputs
    new_scene(old / "scene", {"c0": root / "frames-b"}, calib, ground, fps=5, **quiet)
    write_tacal(root / "c0.tacal", camera_to_tacal(cam))
    from seg2pose.io.tacal import scene_from_tacals
    scene_from_tacals([root / "c0.tacal"], ground, old / "tacal", 25.0)
    # annotate export: an older export set of fewer edits
    ann = make_scene(root / "ann", n_frames=20).root
    with Project.open(ann) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
        p.set_keyframe(1, 10, -2.0, -1.5, heading=0.0)
        with _cl.redirect_stdout(None):
            export_set(p, old / "ann-export", gt=False, mcap=True, tanalyst=True,
                       start="00:00:00.000", force=True)
        shutil.copy2(ann / "gt" / "poses.csv", old / "ann-gt-elsewhere.csv")
        from annotate.export import export_gt
        export_gt(p, old / "ann-poses.csv", force=True)
        p.create_track("pedestrian")
        p.set_keyframe(2, 2, 1.0, 2.0, heading=1.0)
        p.set_keyframe(2, 12, 1.0, 4.0)
        with _cl.redirect_stdout(None):  # import-mcap --force: this set over the older one's
            export_set(p, root / "mcap-new", gt=False, mcap=True, tanalyst=False,
                       start="00:00:00.000", force=True)
    from s2p_review.mcap_import import import_mcap
    from seg2pose.cli.review import _check_restored_journal

    import_mcap(old / "ann-export" / "annotations.mcap", old / "restored",
                check_annotations=_check_restored_journal)
    restored = [old / "restored" / n for n in ("scene.json", load_scene(ann).ground_file,
                                               "out/annotations", "annotations")]
    imp = out / "restored"
    (old / "video").mkdir()  # a file of the scene folder that the import does not write
    (old / "video" / "keep.txt").write_text("not an output of import-mcap\n")
    # import-tanalyst: into a project with one track
    tan = make_scene(root / "tan", n_frames=30).root
    with Project.open(tan) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
    shutil.copytree(tan / "annotations", old / "tan-annotations")
    (root / "t.csv").write_text("\n".join([
        "Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp",
        "1;Car;3;-8;-1,5;12:00:00.000", "2;Car;3;-5;-1,5;12:00:00.500",
        "3;Car;3;-2;-1,5;12:00:01.000", "4;Pedestrian;7;1;2;12:00:00.200",
        "5;Pedestrian;7;1;4;12:00:00.600"]) + "\n")
    # associate: two cameras' tracker ids -> one id per road user (masks/ replaced as a unit)
    aso = make_scene(root / "aso", n_frames=12).root
    shutil.copytree(aso / "masks", old / "aso-masks")
    # batch --serial: a study of one video scene, masks-from-video then run
    study = root / "study"
    study.mkdir()
    new_scene(study / "s1", {"c0": root / "frames"}, calib, ground, fps=10, **quiet)
    s1 = load_scene(study / "s1")
    s1.extra["video_masks"] = bgd
    s1.save()
    # batch on a local Ray of its own (one CPU), its driver killed: the same study
    shutil.copytree(study, root / "study-ray")
    sray = root / "study-ray"
    exp = ann / "export"
    return [
        Case("masks-from-video", ["masks-from-video", mfv, "--no-progress", "--force", *bg],
             [mfv / "masks" / "c0.txt"], [old / "mfv-c0.txt"]),
        Case("import-detections", ["import-detections", imd, dets, "--camera", "c0", "--force"],
             [imd / "masks" / "c0.txt"], [old / "imd-c0.txt"]),
        Case("track", ["track", trk, "--no-progress"], [trk / "masks" / "c0.txt"],
             [old / "trk-c0.txt"]),
        Case("new-scene", ["new-scene", "-o", out / "scene", "--video", f"c0={root / 'frames'}",
                           "--calibration", calib, "--ground", ground, "--fps", "10", "--force"],
             [out / "scene"], [old / "scene"]),
        Case("import-tacal", ["import-tacal", root / "c0.tacal", "--ground", ground, "-o",
                              out / "tacal", "--fps", "10", "--force"], [out / "tacal"],
             [old / "tacal"]),
        Case("annotate-export", ["annotate", "export", ann, "--force"],
             [ann / "gt" / "poses.csv", exp / "annotations.mcap", exp / "annotations.layout.json",
              exp / "tanalyst.csv"],
             [old / "ann-poses.csv", old / "ann-export" / "annotations.mcap",
              old / "ann-export" / "annotations.layout.json", old / "ann-export" / "tanalyst.csv"]),
        Case("import-tanalyst", ["annotate", "import-tanalyst", tan, root / "t.csv", "--start",
                                 "12:00:00.000"], [tan / "annotations"],
             [old / "tan-annotations"], state=_project_state(tan)),
        Case("associate", ["associate", aso, "--force"], [aso / "masks"], [old / "aso-masks"]),
        Case("import-mcap", ["import-mcap", root / "mcap-new" / "annotations.mcap", "-o", imp,
                             "--force"],
             [imp / r.relative_to(old / "restored") for r in restored] + [imp / "video"],
             restored + [old / "video"]),
        Case("batch-serial", ["batch", study, "masks-from-video", "run", "--baseline", "--serial",
                              "--no-progress"],
             [study / "s1" / "masks", study / "s1" / "batch", study / "summary.json"],
             [None, None, None],
             state=_state_of(study / "s1" / "masks" / "c0.txt", study / "s1" / "batch" / "baseline"),
             resume=True),
        Case("batch-ray", ["batch", sray, "masks-from-video", "run", "--baseline", "--cpus", "1",
                           "--no-progress"],
             [sray / "s1" / "masks", sray / "s1" / "batch", sray / "summary.json"],
             [None, None, None],
             state=_state_of(sray / "s1" / "masks" / "c0.txt", sray / "s1" / "batch" / "baseline"),
             resume=True, tree=True,
             rerun=["batch", sray, "masks-from-video", "run", "--baseline", "--serial",
                    "--no-progress"]),
    ]

