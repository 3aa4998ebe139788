"""Issue 12 item 18: --version, an example on every help page (groups too), unit-suffixed option names
with the old names kept as aliases."""

from __future__ import annotations

import re

import pytest

from pipeline.args import UsageError
from pipeline.cli import build_parser, main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert re.fullmatch(r"envfuse (\d+\.\d+\.\d+\S*|unknown)\n", capsys.readouterr().out)


def _help_pages():
    parser = build_parser()
    pages = [((), parser)]
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, gp in sub.choices.items():
        pages.append(((name,), gp))
        for a in gp._actions:
            if a.__class__.__name__ == "_SubParsersAction":
                pages.extend(((name, n), p) for n, p in a.choices.items())
    return pages


def test_every_help_page_has_an_example():
    pages = _help_pages()
    assert len(pages) >= 10
    for words, p in pages:
        assert "Example: envfuse" in p.format_help(), " ".join(words) or "envfuse"


def test_examples_use_the_new_option_names():
    for words, p in _help_pages():
        text = p.epilog or ""
        for old in ("--duration ", "--cell-size ", "--start-east ", "--start-north "):
            assert old not in text, (words, old)


@pytest.mark.parametrize("new,old,dest", [
    ("--duration-s", "--duration", "duration"),
    ("--cell-size-m", "--cell-size", "cell_size"),
    ("--start-east-m", "--start-east", "start_east"),
    ("--start-north-m", "--start-north", "start_north"),
])
def test_old_names_are_aliases(new, old, dest):
    parser = build_parser()
    base = {"duration": ["simulate", "walk", "s", "--seed", "1", "--out", "o"],
            "cell_size": ["simulate", "survey", "s", "--out", "o"],
            "start_east": ["features", "imu", "x.csv", "--out", "o"],
            "start_north": ["features", "imu", "x.csv", "--out", "o"]}[dest]
    a = parser.parse_args(base + [new, "12"])
    b = parser.parse_args(base + [old, "12"])
    assert getattr(a, dest) == getattr(b, dest) == 12.0


# The parser is built for every command; the method registry (walks: the fusion methods, GTSAM, scipy.stats) is
# imported only when a value is checked against it or a help page naming it is printed (pipeline.args.LazyChoices).

def _modules_after(code: str) -> set:
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", code + "\nimport json, sys; print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True)
    return set(json.loads(out.stdout.splitlines()[-1]))


def test_help_and_other_commands_do_not_import_the_method_registry():
    loaded = _modules_after("from pipeline.cli import build_parser\n"
                            "p = build_parser()\n"
                            "p.format_help()\n"
                            "p.parse_args(['simulate', 'walk', 's', '--seed', '1', '--out', 'o'])\n"
                            "p.parse_args(['run', 'w', '--model', 'm', '--out', 'o.csv'])\n"
                            "p.parse_args(['evaluate', 'w', '--model', 'm', '--report', 'r'])")
    assert not {"walks", "walks.methods", "gtsam", "scipy.stats"} & loaded
    loaded = _modules_after("from pipeline.cli import build_parser\n"
                            "build_parser().parse_args(['run', 'w', '--model', 'm', '--out', 'o', '--method', 'kf'])")
    assert "walks.methods" in loaded


def test_method_choices_are_the_registry_s():
    from walks.methods import method, method_names

    parser = build_parser()
    base = ["run", "w", "--model", "m", "--out", "o.csv"]
    assert parser.parse_args(base).method == "kf_quality+lag"     # pipeline.commands.fuse.DEFAULT_METHOD
    assert parser.parse_args(base).segment_s is None  # the command reads walks.segments.SEGMENT_S
    for name in ("kf_quality+rts", "adaptive+lag", "fg_isam2", "foot_ins_fkf"):
        assert parser.parse_args(base + ["--method", name]).method == name
    # a smoothed name of a method that is no filter, a base name misspelt: usage errors naming the choices
    for bad in ("gnss+rts", "adaptiv", "kf+lag+rts"):
        # (argparse quotes the choices up to Python 3.12.6 and 3.13.0, not after)
        with pytest.raises(UsageError, match=r"invalid choice: '.*' \(choose from '?gnss'?, '?acoustic"):
            parser.parse_args(base + ["--method", bad])
    args = parser.parse_args(["evaluate", "a", "b", "--model", "m", "--report", "r", "--methods", "kf", "imm"])
    assert args.methods == ["kf", "imm"]
    assert parser.parse_args(["evaluate", "a", "--model", "m", "--report", "r"]).methods is None
    with pytest.raises(UsageError, match="invalid choice: 'kf\\+rts'"):
        parser.parse_args(["evaluate", "a", "--model", "m", "--report", "r", "--methods", "kf+rts"])
    # run's help page names every method, and the filters among them (a +rts / +lag variant each)
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    text = " ".join(sub.choices["run"].format_help().split())
    names = method_names()
    listed = text.split("one of ", 1)[1].split(";", 1)[0]
    assert listed.replace("- ", "-").split(", ") == list(names)
    filters = text.split("(the filters: ", 1)[1].split(")", 1)[0].split(", ")
    assert filters == [n for n in names if method(n).filter] and "kf_quality" in filters and "gnss" not in filters
    assert "(default 300, 60 to 1e+06" in text and "each with 20 s of warm-up (120 s for fg_*" in text


def test_cli_help_is_one_page_per_command(capsys):
    for argv in (["--help"], ["run", "--help"], ["evaluate", "--help"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.count("usage: envfuse") == 3 and "--method METHOD" in out and "--methods METHOD [METHOD ...]" in out
