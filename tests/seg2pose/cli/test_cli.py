"""The command layer: grouped help, Ctrl-C and errors as one line."""

from __future__ import annotations

import sys

import pytest
from typer.testing import CliRunner


def run_main(monkeypatch, capsys, *argv):
    from seg2pose.cli import main

    monkeypatch.setattr(sys, "argv", ["s2p", *argv])
    with pytest.raises(SystemExit) as e:
        main()
    out = capsys.readouterr()
    return e.value.code, out.out, out.err


def test_help_groups_commands():
    from seg2pose.cli import app

    r = CliRunner().invoke(app, ["--help"], terminal_width=200)
    assert r.exit_code == 0
    text = r.output
    # each panel's title comes before the commands it holds
    order = ["Scene", "synth", "heights", "Method", "train", "paper-table", "Review", "export"]
    pos = [text.index(w) for w in order]
    assert all(a < b for a, b in zip(pos[:3], pos[1:3])) and pos[0] < pos[1] < pos[3] < pos[4] < pos[6]
    for panel, cmd in (("Scene", "info"), ("Method", "run"), ("Review", "review")):
        assert text.index(panel) < text.index(f" {cmd} ")


def test_ctrl_c_is_one_line_and_exit_130(monkeypatch, capsys):
    import seg2pose.io.scene as S

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(S, "load_scene", interrupted)
    code, out, err = run_main(monkeypatch, capsys, "info", "somewhere")
    assert code == 130
    assert err.strip() == "interrupted; finished files are kept, partial ones were not written"


def test_error_is_one_line_exit_2(monkeypatch, capsys, tmp_path):
    code, _, err = run_main(monkeypatch, capsys, "info", str(tmp_path))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith("error: ") and "scene.json" in err


def test_usage_error_exit_2_and_success_exit_0(monkeypatch, capsys):
    code, _, err = run_main(monkeypatch, capsys, "info", "--no-such-option")
    assert code == 2 and "--no-such-option" in err
    code, out, _ = run_main(monkeypatch, capsys, "heights", "--help")
    assert code == 0 and "bisection" in out


def test_one_cli_style():
    """Every option has help in the user's words (no code paths), booleans are --x/--no-x,
    outputs are -o/--out, and every command has a one-line summary."""
    import click
    import typer

    from seg2pose.cli import app

    root = typer.main.get_command(app)
    assert len(root.commands) >= 14
    commands = dict(root.commands)
    for name, group in root.commands.items():  # command groups: their commands too
        commands.update({f"{name} {k}": c for k, c in getattr(group, "commands", {}).items()})
    for name, cmd in commands.items():
        summary = (cmd.help or "").strip().splitlines()[0]
        assert summary.endswith(".") and len(summary) <= 100, (name, summary)
        for p in cmd.params:
            if not isinstance(p, click.Option) or p.name == "help":
                continue
            where = f"{name} {p.opts[0]}"
            assert p.help and p.help.strip(), f"{where}: no help"
            for code_word in ("seg2pose.", "seg2pose/", ".py", "s2p_review"):
                assert code_word not in p.help, f"{where}: help names code ({code_word})"
            if p.is_flag and p.name != "force":
                assert p.secondary_opts and p.secondary_opts[0].startswith("--no-"), \
                    f"{where}: a boolean is --x/--no-x"
            if p.name == "out":
                assert set(p.opts) == {"-o", "--out"}, where
            if p.name == "config":
                assert "-c" in p.opts, where


def test_library_field_becomes_the_flag():
    """A library error about a parameter names the command's option (the command layer
    translates); one about a file is left as it is."""
    from seg2pose.cli.common import speaks_flags
    from seg2pose.core.errors import InputError

    def cmd(rig: str = typer_option("--rig"), out: str = typer_option("-o", "--out")) -> None:
        if rig == "file":
            raise InputError("bad", file="r.json", field="rig")
        raise InputError(f"unknown rig {rig!r}", field="rig" if rig else "out")

    wrapped = speaks_flags(cmd)
    with pytest.raises(InputError, match=r"^field '--rig': unknown rig 'x'$"):
        wrapped(rig="x")
    with pytest.raises(InputError, match=r"^field '--out': "):
        wrapped(rig="")
    with pytest.raises(InputError, match=r"^r.json: field 'rig': bad$"):
        wrapped(rig="file")


def test_library_field_becomes_the_flag_of_a_shared_option(monkeypatch):
    """The same for options declared by a shared Annotated alias (``setting: TrackerSettings
    = []``), where typer reads Option's first argument as the option's name: ``setting`` is
    spoken of as --set, ``progress`` as --progress."""
    import seg2pose.video.video_scene as VS
    from seg2pose.cli.common import speaks_flags
    from seg2pose.cli.video import track_cmd
    from seg2pose.core.errors import InputError

    def refuse(*a, tracker, **k):
        raise InputError("bad", field=tracker["field"])
    monkeypatch.setattr(VS, "scene_track", refuse)
    wrapped = speaks_flags(track_cmd)
    for field, flag in (("setting", "--set"), ("progress", "--progress"), ("classes", "--classes")):
        with pytest.raises(InputError, match=f"^field '{flag}': bad$"):
            wrapped("sc", None, [f"field={field}"], False, True, True)


def typer_option(*decls):
    import typer

    return typer.Option("", *decls)
