"""Every command's --help is right: its usage line names the command as a user types it, its description
is whole sentences, -q/--quiet and -v/--verbose are there, and the internal batch-worker is in no help."""

import re
import subprocess
import sys

import pytest

from facecap.facecap_addon import cli

COMMANDS = sorted(cli.COMMANDS)


def help_text(capsys, argv):
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    assert stop.value.code == 0
    return capsys.readouterr().out


def description(text):
    """The paragraph after the usage block (argparse puts the description there)."""
    blocks = text.split("\n\n")
    return " ".join(blocks[1].split())


def test_the_command_list_is_the_parsers():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert sorted(sub.choices) == COMMANDS and "batch-worker" not in sub.choices


@pytest.mark.parametrize("command", COMMANDS)
def test_command_help_has_its_usage_line_and_a_whole_description(capsys, command):
    text = help_text(capsys, [command, "--help"])
    assert text.startswith(f"usage: facecap {command} "), text.splitlines()[0]
    about = description(text)
    assert re.fullmatch(r"[A-Z][^\n]{40,}[.)]", about), f"{command}: description {about!r}"
    assert not about.endswith((" from.", " the.", " a.", " an.", " of.")), about  # cut mid-sentence
    assert "-q, --quiet" in text and "-v, --verbose" in text, f"{command}: no -q/-v in its help"


def test_top_level_help_lists_every_command_and_hides_the_worker(capsys):
    text = help_text(capsys, ["--help"])
    assert text.startswith("usage: facecap ")
    for command in COMMANDS:
        assert re.search(rf"^\s+{re.escape(command)}\s+\S", text, re.M), f"{command} missing from facecap --help"
    assert "batch-worker" not in text and "--version" in text


def test_version(capsys):
    text = help_text(capsys, ["--version"])
    assert re.fullmatch(r"facecap \d+\.\d+\.\d+\S*\n", text), text


def test_quiet_and_verbose_go_before_or_after_the_command(capsys):
    assert cli.main(["-q", "inspect", "no_such_file.csv"]) == 1
    assert cli.main(["inspect", "no_such_file.csv", "--verbose"]) == 1
    err = capsys.readouterr().err
    assert err.count("no_such_file.csv") == 2 and "unrecognized" not in err


def test_help_through_the_module_entry_names_facecap():
    """``python -m facecap compare --help`` once said ``usage: python -m facecap.solvers.tools.compare``."""
    run = subprocess.run([sys.executable, "-m", "facecap", "compare", "--help"], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0 and run.stdout.startswith("usage: facecap compare "), run.stdout[:200]


def test_a_closed_pipe_ends_quietly(tmp_path):
    """``facecap inspect --json FILE | head -1``: no BrokenPipeError traceback, the status of a SIGPIPE (the
    JSON, ~150 KB, is more than the pipe holds)."""
    take = tmp_path / "take.csv"
    take.write_text("frame," + ",".join(f"m{i}_x,m{i}_y,m{i}_z" for i in range(1500)) + "\n"
                    + "".join(f"{f}," + ",".join("0.01" for _ in range(4500)) + "\n" for f in range(1, 30)))
    proc = subprocess.Popen([sys.executable, "-m", "facecap", "inspect", "--json", str(take)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.readline()
    proc.stdout.close()  # as `head -1` does
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141, err
    assert "Traceback" not in err and "BrokenPipe" not in err, err
