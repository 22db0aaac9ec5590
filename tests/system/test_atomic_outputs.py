"""Outputs are written as units (issue 10): ``--force`` replaces an output entirely instead of
merging into it, a second concurrent writer is refused, the leftovers of killed writers are
cleaned up, crafted MCAP files cannot write outside their folder, and failures of the
operating system (disk full, a file in the way, a read-only folder) end in one line naming
the output, with earlier outputs intact."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hostile_fixtures import write_s2p_mcap, write_scene, write_utocs

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.atomic import clean_stale_partials, replacing
from seg2pose.io.mots import read_mots
from seg2pose.io.scene import load_scene

ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}


def s2p(*args, cwd=None, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", "from seg2pose.cli import main; main()", *map(str, args)],
                          capture_output=True, text=True, env=ENV, cwd=cwd, timeout=timeout)


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


@contextlib.contextmanager
def held_lock(path: Path):
    """Another live process holding the output lock of ``path``."""
    code = ("import sys, time; from seg2pose.io.atomic import output_lock\n"
            "with output_lock(sys.argv[1]):\n    print('held', flush=True); time.sleep(60)")
    p = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True,
                         env=ENV)
    try:
        assert p.stdout.readline().strip() == "held"
        yield p.pid
    finally:
        p.kill()
        p.wait()


# --- --force replaces as a unit -------------------------------------------------------------------

def test_convert_masks_force_replaces_a_png_folder(tmp_path):
    """Old main: 'convert-masks --format png --force' over a longer folder kept its other
    frames, which were then read back with the new ones."""
    from seg2pose.io.mask_formats import save_masks
    from seg2pose.io.png import list_frames, read_png_folder

    s = write_scene(tmp_path / "s", frames=8)
    long = read_mots(s.masks_path("c0"))
    save_masks(tmp_path / "png", long, "png")
    assert len(list_frames(tmp_path / "png")) == 8
    short = long.take(long.frame < 2)
    with pytest.raises(S2PError, match="exists; pass --force to replace it"):
        save_masks(tmp_path / "png", short, "png")
    save_masks(tmp_path / "png", short, "png", force=True)
    assert [f for f, _ in list_frames(tmp_path / "png")] == [0, 1]
    assert len(read_png_folder(tmp_path / "png")) == len(short)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["png", "s"]  # no temporary left


def test_import_utocs_force_replaces_the_scene(tmp_path):
    """Old main: 'import-utocs --force' kept the old scene's masks, frames and cameras."""
    from seg2pose.io.utocs import import_utocs

    two = [dict(id=0, x=-12.0, y=3.0, z=6.0, pitch=-25.0, roll=0.0, yaw=20.0),
           dict(id=5, x=12.0, y=3.0, z=6.0, pitch=-25.0, roll=0.0, yaw=160.0)]
    import_utocs(write_utocs(tmp_path / "a", cams=two, images=True), tmp_path / "out", log=lambda *a: None)
    (tmp_path / "out" / "masks" / "cam5.txt").write_text("")
    assert (tmp_path / "out" / "video" / "cam5").is_dir()
    with pytest.raises(S2PError, match="exists; pass --force"):
        import_utocs(write_utocs(tmp_path / "b"), tmp_path / "out", log=lambda *a: None)
    import_utocs(tmp_path / "b", tmp_path / "out", force=True, log=lambda *a: None)
    out = tmp_path / "out"
    assert not (out / "masks" / "cam5.txt").exists() and not (out / "video").exists()
    assert json.loads((out / "scene.json").read_text())["cameras"][0]["name"] == "cam0"
    assert len(json.loads((out / "scene.json").read_text())["cameras"]) == 1


def test_replacing_swaps_file_and_folder_and_keeps_the_old_on_error(tmp_path):
    out = tmp_path / "o"
    with replacing(out) as tmp:
        (tmp / "a").write_text("1")
    with pytest.raises(RuntimeError):
        with replacing(out, force=True) as tmp:
            (tmp / "b").write_text("2")
            raise RuntimeError("boom")
    assert sorted(p.name for p in out.iterdir()) == ["a"]
    with replacing(out, force=True, folder=False) as tmp:
        tmp.write_text("file now")
    assert out.read_text() == "file now"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


# --- one writer at a time; leftovers of killed writers --------------------------------------------

def test_second_concurrent_writer_is_refused(tmp_path):
    """Old main: two 's2p run' (or 's2p synth') into one folder at once both succeeded."""
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    write_scene(tmp_path / "s")
    with held_lock(tmp_path / "run") as pid:
        with pytest.raises(S2PError, match=rf"run is being written by process {pid}"):
            run_scene(load_scene(tmp_path / "s"), tmp_path / "run", RunOptions(baseline=True, progress=False))
    with held_lock(tmp_path / "syn") as pid:
        with pytest.raises(S2PError, match=rf"syn is being written by process {pid}"):
            generate_scene(tmp_path / "syn", SynthOptions(frames=4, workers=1, progress=False))
    # only the killed holders' (stale) locks remain, which the next writer takes over
    assert sorted(p.name for p in tmp_path.iterdir()) == [".run.lock", ".syn.lock", "s"]


def test_stale_partials_of_dead_processes_are_cleaned(tmp_path, capsys):
    """A killed synth left .OUT.partial-PID behind for good; now the next writer of OUT
    removes the partials (and the lock) of processes that no longer run, and keeps those of
    live ones."""
    from seg2pose.synth.generate import SynthOptions, generate_scene

    out = tmp_path / "syn"
    pid = dead_pid()
    (tmp_path / f".syn.partial-{pid}" / "masks").mkdir(parents=True)          # old main's name
    (tmp_path / f".syn.partial-{pid}-x1y2").mkdir()
    (tmp_path / f".syn.partial-{pid}-k3.tmp").write_text("half")
    (tmp_path / ".syn.lock").write_text(json.dumps({"pid": pid, "host": os.uname().nodename}))
    live = tmp_path / f".syn.partial-{os.getpid()}-mine"
    live.mkdir()
    other = tmp_path / f".other.partial-{pid}"
    other.mkdir()
    generate_scene(out, SynthOptions(frames=4, workers=1, progress=False))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f".other.partial-{pid}", live.name, "syn"])
    assert "taking over the lock" in capsys.readouterr().err
    assert clean_stale_partials(tmp_path / "other") == [other]


# --- crafted MCAP files ---------------------------------------------------------------------------

GOOD_ROW = {"frame": 0, "track_id": 1, "class": "car", "x": 1.0, "y": 2.0, "z": 0.0,
            "heading": 0.5, "l": 4.0, "w": 2.0, "h": 1.5}


@pytest.mark.parametrize("name", ["../escaped.csv", "/tmp/s2p-escaped-{}.csv", "a/../../escaped.csv"])
def test_import_mcap_refuses_paths_outside_the_folder(tmp_path, name):
    """Old main wrote the file named inside the embedded scene.json wherever it pointed,
    without --force."""
    from s2p_review.mcap_import import import_mcap

    name = name.format(os.getpid())
    f = write_s2p_mcap(tmp_path / "x.mcap", {"version": 1, "ground_points": name}, name,
                       [{"frame": 0, "rows": [GOOD_ROW]}])
    with pytest.raises(InputError, match=r"x\.mcap: field 'scene.json attachment: ground_points': "
                                         r"ground points file .* leads outside"):
        import_mcap(f, tmp_path / "out")
    assert not (tmp_path / "escaped.csv").exists() and not Path(name).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]


def test_import_mcap_refuses_a_crafted_run_name(tmp_path):
    from s2p_review.mcap_import import import_mcap

    f = write_s2p_mcap(tmp_path / "x.mcap", {"version": 1}, "ground_points.csv", [], run_name="../../r")
    with pytest.raises(InputError, match=r"run name '\.\./\.\./r' cannot be used in a file name"):
        import_mcap(f, tmp_path / "out")


@pytest.mark.parametrize("rows,match", [
    ([{"frame": 0}], r"malformed /s2p/poses message 0 \(frame 0\): KeyError"),
    ([{"frame": 0, "rows": [dict(GOOD_ROW, x="a")]}], r"malformed /s2p/poses message 0"),
    ([{"frame": 0, "rows": [dict(GOOD_ROW, x=None)]}],
     r"the restored poses\.csv would be invalid \(row 1\): x, y, z must be finite"),
    ([{"frame": 0, "rows": [GOOD_ROW, GOOD_ROW]}],
     r"the restored poses\.csv would be invalid \(row 2\): duplicate row"),
    ([{"frame": 0, "rows": [dict(GOOD_ROW, l=-4)]}],
     r"the restored poses\.csv would be invalid \(row 1\): l, w, h must be finite metres in"),
])
def test_import_mcap_malformed_rows_are_one_error(tmp_path, rows, match):
    from s2p_review.mcap_import import import_mcap

    f = write_s2p_mcap(tmp_path / "x.mcap", {"version": 1}, "ground_points.csv", rows)
    with pytest.raises(InputError, match=r"x\.mcap: " + match):
        import_mcap(f, tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]


def test_import_mcap_malformed_rows_one_line_in_the_cli(tmp_path):
    f = write_s2p_mcap(tmp_path / "x.mcap", {"version": 1}, "ground_points.csv", [{"frame": 0}])
    r = s2p("import-mcap", f, "-o", tmp_path / "out")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [f"error: {f}: malformed /s2p/poses message 0 (frame 0): "
                                             "KeyError: 'rows'"]


# --- the operating system says no: one line, nothing lost -----------------------------------------

def test_output_under_a_file_is_one_line(tmp_path):
    s = write_scene(tmp_path / "s")
    (tmp_path / "file").write_text("keep me")
    r = s2p("convert-masks", s.masks_path("c0"), "-o", tmp_path / "file" / "m.json", "--format", "coco")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines() == [
        f"error: cannot write {tmp_path / 'file' / 'm.json'}: a file is in the way where a folder "
        f"is needed ({tmp_path / 'file'})"]
    assert (tmp_path / "file").read_text() == "keep me"


@contextlib.contextmanager
def mounted_tmpfs(where: Path, options: str):
    where.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or 'mount failed'}); the disk-full "
                    "and read-only cases need one")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def test_read_only_folder_is_one_line(tmp_path):
    s = write_scene(tmp_path / "s")
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        ctx = contextlib.nullcontext(ro)
    else:  # root writes anywhere a mode allows nothing; a read-only mount stops root too
        ctx = mounted_tmpfs(tmp_path / "ro", "ro,size=1m")
    with ctx as ro:
        r = s2p("run", s.root, "-o", ro / "run", "--baseline")
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        line, = r.stderr.strip().splitlines()[-1:]
        assert line.startswith(f"error: cannot write {ro / 'run'}: ") and (
            "read-only" in line or "permission denied" in line), line
        assert os.listdir(ro) == []


def fill_leaving(path: Path, free: int) -> None:
    """Fill the file system of ``path`` up, then give back ``free`` bytes."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
    with contextlib.suppress(OSError):
        while True:
            os.write(fd, b"\0" * 4096)
    os.close(fd)
    size = path.stat().st_size
    os.truncate(path, max(0, size - free))


def test_disk_full_is_one_line_and_keeps_the_old_run(tmp_path):
    """'run --force' onto a full disk: old main left poses.csv of one run beside views.csv
    and run.json of another; now the old run stays whole and one line names the output."""
    from seg2pose.io.run import read_run_meta

    s = write_scene(tmp_path / "s", frames=30, users=3)
    with mounted_tmpfs(tmp_path / "small", "size=64k") as small:
        assert s2p("run", s.root, "-o", small / "run", "--baseline").returncode == 0
        before = {p.name: p.read_bytes() for p in (small / "run").iterdir()}
        fill_leaving(small / "filler", 8192)  # room for the lock, not for the new poses.csv
        r = s2p("run", s.root, "-o", small / "run", "--baseline", "--force")
        assert r.returncode == 2, r.stderr
        assert "Traceback" not in r.stderr, r.stderr
        full = f"error: cannot write {small / 'run' / 'poses.csv'}: the disk is full"
        assert r.stderr.strip().splitlines()[-1] == full
        assert {p.name: p.read_bytes() for p in (small / "run").iterdir()} == before
        assert read_run_meta(small / "run")["n_poses"] > 0
        assert sorted(p.name for p in small.iterdir()) == ["filler", "run"]


def test_ctrl_c_is_one_line_and_leaves_nothing(tmp_path):
    """Old main: exit 130 and nothing printed (typer swallowed the interrupt)."""
    import signal

    # the child gets SIGINT's default disposition: an ignored SIGINT is inherited across exec,
    # and in a full run some test before this one leaves it ignored in the pytest process --
    # then synth never saw the interrupt, finished, and this test skipped itself every time
    p = subprocess.Popen([sys.executable, "-c", "from seg2pose.cli import main; main()", "synth",
                          "-o", str(tmp_path / "syn"), "--frames", "400", "--workers", "1", "--no-progress"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while p.poll() is None and time.monotonic() < deadline:  # interrupt it while it writes
        if any(n.startswith(".syn.partial-") for n in os.listdir(tmp_path)):
            break
        time.sleep(0.05)
    time.sleep(0.3)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    assert p.returncode != 0, "synth finished before the interrupt: it never saw it"
    assert p.returncode == 130, err
    # the output is named (issue 38: the README promised it, the line did not say it)
    assert err.strip().splitlines() == [f"interrupted; {tmp_path / 'syn'} not written (left as it was); "
                                        "finished files are kept, partial ones were not written"]
    assert os.listdir(tmp_path) == []
