"""The docs as a newcomer uses them: every command block of README.md and docs/guide/*.md runs
as written, in order, in a fresh folder per page, with the installed ``s2p``.

Blocks are fenced by what they hold: ```sh (shell commands: run, line by line) and ```python
(run as one script) are run; ```text (printed output, file layouts) and ```csv / ```json (file
formats) are not. A block with no such mark fails the test, so nothing is silently left out.

What the test adds, each for a reason a reader can see:

- the reader's own files (a video of the junction, an aerial image, pairs, a calibration, a
  detector's COCO output, T-Analyst and UTOCS files) are made first from one small synthetic
  junction with video (tests/doc_givens.py), under the names the docs use;
- a command a doc marks ``(quick check: OPTIONS)`` in its comment runs with those options (the
  docs mark so the commands that take CPU minutes: training);
- a page (``s2p annotate SCENE``, ``s2p calibrate-camera ... --aerial/--survey``) runs with
  ``--no-browser`` (no browser here): the test waits for the printed URL, checks that the page
  answers with the token and refuses without it, does the reader's part (on the calibration page
  eight pairs, Solve, Save, through the page's API; after the annotation app, a few keyframes
  through the annotation API), then stops the server with Ctrl-C (SIGINT), which must exit 0;
- ``make demo`` / ``make test`` (the set-up itself: SKIP) are not run;
- a ```text block right after a sh block that the prose says the command "prints" must be what
  the block's last command prints (a trailing "in N s" time aside).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = [README, *sorted((ROOT / "docs" / "guide").glob("*.md"))]
MAX_LINES = 250
RUN = {"sh", "python"}
NOT_RUN = {"text", "csv", "json"}  # printed output and file formats
# lines not run, by their start: why
SKIP = {
    "make demo": "the set-up itself (installs, then the demo: minutes)",
    "make test": "the set-up itself (the whole suite, this test included)",
}
ANNOTATE_SUBCOMMANDS = {"open", "status", "import-tanalyst", "export-tanalyst", "export"}
URL = re.compile(r"http://127\.0\.0\.1:\d+/\?access_token=[\w-]+")


def blocks(text: str) -> list[tuple[str, int, list[str], str]]:
    """(language, line number of the fence, lines, the prose before the block) per fenced block."""
    out, lang, start, body, prose = [], None, 0, [], []
    for i, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            if lang is None:
                lang, start, body = line[3:].strip(), i, []
            else:
                out.append((lang, start, body, "\n".join(prose)))
                lang, prose = None, []
            continue
        (body if lang is not None else prose).append(line)
    return out


def shell_lines(body: list[str]) -> list[tuple[str, str]]:
    """(command, comment) per command of a sh block: continuation lines joined, comment lines
    and comments dropped (a comment-only line after a command continues its comment)."""
    out: list[tuple[str, str]] = []
    pending, after_command = "", False
    for line in body:
        cmd, _, comment = line.partition(" #") if not line.lstrip().startswith("#") else ("", "", line)
        cmd = pending + cmd.strip()
        if cmd.endswith("\\"):
            pending = cmd[:-1].rstrip() + " "
            continue
        pending = ""
        if cmd:
            out.append((cmd, comment.strip(" #")))
        elif after_command and comment.strip():  # a comment line right under a command: its comment
            out[-1] = (out[-1][0], (out[-1][1] + " " + comment.strip(" #")).strip())
        after_command = bool(cmd) or (after_command and bool(comment.strip()))
    return out


def quick_check(comment: str) -> list[str]:
    m = re.search(r"quick check: ([^)]*)", comment)
    return shlex.split(m.group(1).replace("`", "")) if m else []


def page_of(argv: list[str]) -> str | None:
    """Which page a command serves until Ctrl-C: "annotate", "calibrate" or None."""
    if argv[:2] == ["s2p", "annotate"] and len(argv) > 2 and argv[2] not in ANNOTATE_SUBCOMMANDS:
        return "annotate"
    if argv[:2] == ["s2p", "calibrate-camera"] and ({"--aerial", "--survey"} & set(argv)) \
            and not ({"--points", "--from-traffic"} & set(argv)):
        return "calibrate"
    return None


def _env() -> dict:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("PYTHONPATH", None)
    return env


def _get(url: str) -> tuple[int, str]:
    """(status, body), as a browser gets it (cookies kept across the token's redirect); the
    server may print its URL a moment before it listens."""
    import http.cookiejar

    opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
    for _ in range(120):
        try:
            with opener.open(url, timeout=60) as r:
                return r.status, r.read().decode(errors="replace")
        except urllib.error.HTTPError as e:
            return e.code, e.read().decode(errors="replace")
        except urllib.error.URLError:
            time.sleep(0.5)
    raise AssertionError(f"{url}: nothing answers")


def run_page(argv: list[str], cwd: Path, kind: str) -> str:
    from doc_givens import click_calibration_page, place_keyframes

    proc = subprocess.Popen([*argv, "--no-browser"], cwd=cwd, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    said: list[str] = []
    try:
        t0 = time.monotonic()
        url = None
        for line in proc.stdout:  # type: ignore[union-attr]
            said.append(line)
            m = URL.search(line)
            if m:
                url = m.group(0)
                break
            if time.monotonic() - t0 > 180:
                break
        assert url, f"{shlex.join(argv)}: no URL printed\n{''.join(said)[-3000:]}"
        code, page = _get(url)
        assert code == 200 and "<html" in page.lower(), f"{url}: {code}"
        code, why = _get(url.split("?")[0])
        command = "s2p annotate" if kind == "annotate" else "s2p calibrate-camera"
        assert code == 403 and f"`{command}` printed" in why, why
        if kind == "calibrate":
            click_calibration_page(url, cwd)
            out = Path(argv[argv.index("-o") + 1]) if "-o" in argv else None
            assert out is None or (cwd / out).is_file(), f"Save wrote no {out}"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)
    rest = proc.stdout.read()  # type: ignore[union-attr]
    # stopped by Ctrl-C, as the page says: 0, or 130 (the shell's code for SIGINT) with a note
    assert proc.returncode in (0, 130), f"{shlex.join(argv)}: exit {proc.returncode}\n{''.join(said)}{rest}"
    if kind == "annotate":  # the reader's keyframes, placed in the app
        run = argv[argv.index("--run") + 1] if "--run" in argv else None
        place_keyframes(cwd / argv[2], cwd / run if run else None)
    return "".join(said) + rest


# Each command runs in a process forked from one Python that has imported the s2p entry point
# (``seg2pose.cli:main``, what the installed ``s2p`` script calls) and torch: the command's own
# work, not the seconds every torch-using command spends importing it, without changing what it
# does (its own process, argv, working folder, exit code and output; CPU time from wait4).
_FORKSERVER = r"""
import json, os, sys, traceback
sys.argv = ["s2p"]
import numpy, cv2, torch, seg2pose.cli, seg2pose.method.pipeline, seg2pose.method.checkpoint
out = os.fdopen(1, "w", buffering=1)
out.write("ready\n")
for line in sys.stdin:
    argv, cwd, log = json.loads(line)
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            os.chdir(cwd)
            fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            sys.argv = ["s2p", *argv]
            seg2pose.cli.main()
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    _, status, ru = os.wait4(pid, 0)
    out.write(json.dumps([os.waitstatus_to_exitcode(status), ru.ru_utime + ru.ru_stime]) + "\n")
"""


class ForkServer:
    def __init__(self):
        self.p = subprocess.Popen([sys.executable, "-c", _FORKSERVER], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True, env=_env())
        assert self.p.stdout.readline().strip() == "ready"  # type: ignore[union-attr]
        self.cpu = 0.0

    def run(self, argv: list[str], cwd: Path) -> tuple[int, str]:
        log = cwd / ".command.log"
        self.p.stdin.write(json.dumps([argv, str(cwd), str(log)]) + "\n")  # type: ignore[union-attr]
        self.p.stdin.flush()  # type: ignore[union-attr]
        code, cpu = json.loads(self.p.stdout.readline())  # type: ignore[union-attr]
        self.cpu += cpu
        text = log.read_text(errors="replace")
        log.unlink()
        return code, text

    def close(self) -> None:
        self.p.stdin.close()  # type: ignore[union-attr]
        self.p.wait(30)


_server: ForkServer | None = None


def run_line(line: str, comment: str, cwd: Path) -> str:
    global _server
    argv = shlex.split(line)
    assert argv[0] == "s2p", f"a command that is neither s2p nor listed in SKIP: {line}"
    kind = page_of(argv)
    if kind:
        return run_page(argv, cwd, kind)
    if _server is None or _server.p.poll() is not None:
        _server = ForkServer()
    code, text = _server.run(argv[1:] + quick_check(comment), cwd)
    assert code == 0, f"{line}\n{text[-5000:]}"
    return text


def printed(line: str, output: str) -> bool:
    """Whether ``output`` holds the doc's line (a trailing time "in 3.7 s" may differ)."""
    pat = re.sub(r"in\\ [0-9]+(\\.[0-9]+)?\\ s$", r"in\\ [0-9.]+\\ s", re.escape(line.strip()))
    return re.search(pat, output) is not None


def _cpu() -> float:
    """CPU seconds of the commands so far (pages: this process's children; the rest: the
    fork server's)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime + (_server.cpu if _server is not None else 0.0)


def run_doc(doc: Path, cwd: Path) -> list[str]:
    ran: list[str] = []
    last = ""
    bl = blocks(doc.read_text(encoding="utf-8"))
    for lang, start, body, prose in bl:
        where = f"{doc.relative_to(ROOT)}:{start}"
        if lang == "sh":
            for line, comment in shell_lines(body):
                if any(line.startswith(s) for s in SKIP):
                    continue
                t0, cpu0 = time.monotonic(), _cpu()
                last = run_line(line, comment, cwd)
                ran.append(f"{where} {time.monotonic() - t0:5.1f} s {_cpu() - cpu0:5.1f} CPU s  {line}")
                print(ran[-1], flush=True)
        elif lang == "python":
            r = subprocess.run([sys.executable, "-c", "\n".join(body)], cwd=cwd, env=_env(),
                               capture_output=True, text=True, timeout=600)
            assert r.returncode == 0, f"{where}: the python block\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
            ran.append(f"{where} python block")
        elif lang == "text" and "prints" in (prose.strip().splitlines() or [""])[-1]:
            for ln in body:
                assert not ln.strip() or printed(ln, last), \
                    f"{where}: the doc says the command prints\n  {ln}\nit printed\n{last[-2000:]}"
    return ran


def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, f"README.md has {n} lines"


def test_blocks_are_parsed():
    text = "x\n```sh\na --b  # c\nd \\\n  e\n# f\n\n# g\n```\nit prints\n```text\ng\n```\n"
    (lang, start, body, _), (lang2, _, body2, prose) = blocks(text)
    assert (lang, start, lang2, body2, prose) == ("sh", 2, "text", ["g"], "it prints")
    assert shell_lines(body) == [("a --b", "c"), ("d e", "f")]
    assert quick_check("minutes (quick check: --epochs 1 --batches 2)") == ["--epochs", "1", "--batches", "2"]
    assert page_of(["s2p", "annotate", "scenes/x"]) == "annotate"
    assert page_of(["s2p", "annotate", "export", "scenes/x"]) is None
    assert page_of(["s2p", "calibrate-camera", "v.mp4", "--aerial", "a.png"]) == "calibrate"
    assert page_of(["s2p", "calibrate-camera", "--points", "p.csv"]) is None
    assert printed("wrote x: 5 in 3.7 s", "..wrote x: 5 in 12.25 s\n")
    assert not printed("wrote x: 5 in 3.7 s", "wrote x: 6 in 3.7 s")


@pytest.mark.parametrize("doc", DOCS, ids=[d.name for d in DOCS])
def test_every_block_is_run_or_marked(doc):
    for lang, start, _, _ in blocks(doc.read_text(encoding="utf-8")):
        assert lang in RUN | NOT_RUN, (
            f"{doc.relative_to(ROOT)}:{start}: a block fenced ```{lang}: mark it ```sh (commands, "
            f"run by this test), ```python (run) or ```text / ```csv / ```json (not commands)")


def _options(cmd) -> set[str]:
    return {o for p in cmd.params for o in (*p.opts, *p.secondary_opts)}


def inline_command_errors(text: str, root) -> list[str]:
    """The `s2p ...` spans of prose whose command does not exist or that name an option their
    command does not have (a renamed or dropped flag)."""
    bad = []
    for m in re.finditer(r"`(s2p [^`]+)`", text):
        words, cmd, i = m.group(1).split(), root, 1
        while i < len(words) and hasattr(cmd, "commands") and words[i] in cmd.commands:
            cmd, i = cmd.commands[words[i]], i + 1
        if cmd is root:
            if i < len(words) and words[i][:1].islower():
                bad.append(f"`{m.group(1)}`: no command {words[i]!r}")
            continue
        if hasattr(cmd, "commands"):  # `s2p annotate SCENE` is `s2p annotate open SCENE`
            cmd = cmd.commands.get("open", cmd)
        opts = _options(cmd)
        bad += [f"`{m.group(1)}`: no option {w}" for w in
                (w.split("=")[0].rstrip(",.;:)") for w in words[i:]) if w.startswith("--") and w not in opts]
    return bad


def test_inline_commands_name_real_options():
    import typer.main

    from seg2pose.cli import app

    root = typer.main.get_command(app)
    assert inline_command_errors("`s2p conflicts R -o c.csv --near 25`, `s2p frobnicate X`", root) == [
        "`s2p conflicts R -o c.csv --near 25`: no option --near", "`s2p frobnicate X`: no command 'frobnicate'"]
    bad = [f"{d.relative_to(ROOT)}: {b}" for d in DOCS
           for b in inline_command_errors(d.read_text(encoding="utf-8"), root)]
    assert not bad, "\n".join(bad)


@pytest.fixture(scope="module")
def givens(tmp_path_factory):
    from doc_givens import make_givens

    return make_givens(tmp_path_factory.mktemp("givens"))


@pytest.mark.parametrize("doc", DOCS, ids=[d.name for d in DOCS])
def test_doc_commands_run_as_written(doc, givens, tmp_path):
    if not any(lang in RUN for lang, *_ in blocks(doc.read_text(encoding="utf-8"))):
        return
    for f in givens.iterdir():
        if f.is_file():
            shutil.copy(f, tmp_path / f.name)
    shutil.copytree(givens / "SRC", tmp_path / "SRC")
    # the repository's files the docs name by their path (the shipped demo models)
    (tmp_path / "seg2pose" / "data").mkdir(parents=True)
    (tmp_path / "seg2pose" / "data" / "demo_models").symlink_to(ROOT / "seg2pose" / "data" / "demo_models")
    t0, cpu0 = time.monotonic(), _cpu()
    ran = run_doc(doc, tmp_path)
    print(f"{doc.name}: {len(ran)} commands in {time.monotonic() - t0:.0f} s wall, "
          f"{_cpu() - cpu0:.0f} CPU s", *ran, sep="\n  ")
