"""The command line stays small and says what it takes: every verb's parser lives beside its code
(one module per family, none importing the CLI back), every option has help that names the values
it accepts, and ``--help`` is plain text (no reStructuredText markup)."""

import argparse
import re
from pathlib import Path

from priortrack.cli.main import FAMILIES, build_parser

PACKAGE = Path(__file__).resolve().parents[1] / "priortrack"


def _parsers(parser: argparse.ArgumentParser, path: str = "priortrack"):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{path} {name}")


def test_every_option_has_plain_help():
    missing, markup = [], []
    for path, parser in _parsers(build_parser()):
        texts = [parser.description or "", parser.format_help()]
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if not action.help:
                missing.append(f"{path} {'/'.join(action.option_strings) or action.dest}")
            texts.append(action.help or "")
        markup += [path for text in texts if re.search(r"``|:func:|:mod:|:class:", text)]
    assert not missing, missing
    assert not markup, sorted(set(markup))


def test_the_output_options_name_every_format():
    parsers = dict(_parsers(build_parser()))
    outs = {a.dest: a.help for a in parsers["priortrack track"]._actions}
    for suffix in (".npz", ".csv", ".trc", ".bvh"):
        assert suffix in outs["out"]
    assert "JSON" in outs["json"]


def test_one_module_per_family_and_no_import_back():
    assert {f.__name__.rsplit(".", 1)[1] for f in FAMILIES} == {"data", "priors", "track", "compare", "evaluate", "bench"}
    for path in PACKAGE.rglob("*.py"):
        if path.parent.name != "cli":
            assert "priortrack.cli" not in path.read_text(), path
    assert len((PACKAGE / "cli" / "main.py").read_text().splitlines()) < 80
