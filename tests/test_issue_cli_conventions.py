"""Issue 12 item 18: --version, an example on every help page (groups too), unit-suffixed option names
with the old names kept as aliases."""

from __future__ import annotations

import re

import pytest

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
