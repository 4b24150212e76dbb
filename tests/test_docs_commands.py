"""The commands in the documentation work as written: every command of ours in a
code block of README.md and docs/*.md (and in inline code) parses with the
command's own parser, options in their places (``rota-gs --zenoh-config FILE
status`` did not); the runnable ones run (tests/test_cli_*.py, test_deploy_docs.py)."""

from __future__ import annotations

import glob
import re
import shlex

import pytest

from companion.cli import make_parser as companion_parser
from companion.gs.cli import make_parser as gs_parser
from rota.cli import make_parser as rota_parser
from sitl.cli import _parser as sim_parser
from sitl.experiment_cli import _parser as sitl_parser

PARSERS = {"rota": rota_parser, "rota-companion": companion_parser, "rota-gs": gs_parser,
           "rota-sim": sim_parser, "rota-sitl": sitl_parser}
DOCS = sorted(glob.glob("docs/*.md")) + ["README.md"]
#: A command of ours at the start of a line (after sudo or a path to a venv's bin/)
COMMAND = re.compile(r"^(?:sudo\s+)?(?:\S*/bin/)?(rota(?:-companion|-gs|-sim|-sitl)?)(\s.*)?$")


def _lines(text: str) -> list[tuple[str, bool]]:
    """(line, whole) of code blocks (whole) and inline code spans (mentions, maybe
    without their required arguments) that start with one of our commands."""
    out = []
    for block in re.findall(r"```[a-z0-9]*\n(.*?)```", text, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            out.append((line.split(" #")[0].strip(), True))
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    out += [(" ".join(s.split()), False) for s in re.findall(r"`([^`]+)`", prose)]
    return [(ln, whole) for ln, whole in out if COMMAND.match(ln)
            and not re.match(r"^\S+ \S+: ", ln)]  # not an error message ("rota-gs send: ...")


def _argv(line: str) -> tuple[str, list[str]]:
    """The tool and its arguments, with a synopsis's notation resolved: ``[x]`` is x,
    ``a|b`` is a, ``FILE...`` is FILE."""
    tool, rest = COMMAND.match(line).groups()
    argv = []
    for tok in shlex.split(rest or ""):
        tok = tok.strip("[]")
        if "|" in tok and not tok.startswith("tcp/"):
            tok = tok.split("|")[0]
        if tok == "...":  # a value left out: any will do
            tok = "x"
        tok = tok.removesuffix("...")
        if not tok:
            continue
        if re.fullmatch(r"[A-Z]", tok):  # a number's placeholder (N, S)
            tok = "1"
        argv.append(tok)
    return tool, argv


COMMANDS = sorted({(path, line, whole) for path in DOCS
                   for line, whole in _lines(open(path).read())})


def test_the_docs_have_commands_to_check():
    tools = {_argv(line)[0] for _, line, _ in COMMANDS}
    assert tools == set(PARSERS), tools
    assert len(COMMANDS) > 40


@pytest.mark.parametrize(("path", "line", "whole"), COMMANDS)
def test_a_documented_command_parses(path, line, whole, capsys):
    """Inline mentions may leave out required arguments, nothing else."""
    tool, argv = _argv(line)
    if argv in ([], ["--version"], ["--help"]):
        return
    try:
        PARSERS[tool]().parse_args(argv)
    except SystemExit as exc:
        err = capsys.readouterr().err.strip()
        last = err.splitlines()[-1]
        mention = ("arguments are required" in last or "expected one argument" in last
                   or re.search(r"invalid choice: '[A-Z]+'", last))
        if whole or not mention:
            pytest.fail(f"{path}: `{line}` does not parse (exit {exc.code}): {err}")


def test_every_flight_command_is_routed_to_the_flights_cli():
    """rota-sitl sends a command to sitl/flights_cli.py by its first word
    (sitl.entry.FLIGHTS, a list of its own so the entry imports nothing): a flight command
    missing from it reached the experiments' parser and failed there ('startup' did)."""
    import argparse

    from sitl.entry import FLIGHTS
    from sitl.flights_cli import add_flight_commands

    sub = argparse.ArgumentParser().add_subparsers()
    add_flight_commands(sub)
    assert set(sub.choices) == set(FLIGHTS)
