"""The benchmark split: disjoint seeded sites, resumable build, traceable split.toml."""

import pytest

from features.errors import ConfigError
from features.walk import load_walk
from simulation.split import SPLITS, BenchmarkSplit, build_split, split_layout

TINY = BenchmarkSplit("tiny", train_sites=(101,), test_sites=(201,), walks_per_site=1, walk_s=12.0,
                      cell_size_m=40.0, capture_s=1.0)


def test_documented_splits_are_disjoint_and_valid():
    for s in SPLITS.values():
        assert s.later_days or not set(s.train_sites) & set(s.test_sites)
    assert len(SPLITS["standard"].test_sites) >= 5 and len(SPLITS["later_days"].test_sites) >= 5
    with pytest.raises(ConfigError, match="same sites"):
        BenchmarkSplit("bad", train_sites=(1, 2), test_sites=(2,), later_days=True)
    with pytest.raises(ConfigError, match="both training and test"):
        BenchmarkSplit("bad", train_sites=(1, 2), test_sites=(2,))
    with pytest.raises(ConfigError, match="walks_per_site"):
        BenchmarkSplit("bad", train_sites=(1,), test_sites=(2,), walks_per_site=0)


def test_build_is_resumable_and_traceable(tmp_path):
    said = []
    layout = build_split(TINY, tmp_path / "b", progress=said.append)
    assert said == ["site 101", "site 201", "survey 101", "walk 101/w0", "survey 201", "walk 201/w0"]
    assert layout.train_walks == [tmp_path / "b" / "walks" / "101" / "w0"]
    w = load_walk(layout.test_walks[0])
    assert w.duration_s == pytest.approx(12.0)
    assert len(list((layout.survey_dir(201) / "cells").iterdir())) >= 3
    again = []
    build_split(TINY, tmp_path / "b", progress=again.append)
    assert again == []                                   # everything already there: nothing rebuilt
    assert split_layout(tmp_path / "b").split == TINY
    other = BenchmarkSplit("tiny", train_sites=(102,), test_sites=(201,), walks_per_site=1, walk_s=12.0,
                           cell_size_m=40.0, capture_s=1.0)
    with pytest.raises(ConfigError, match="another split"):
        build_split(other, tmp_path / "b")
    with pytest.raises(ConfigError, match="unknown split"):
        build_split("nope", tmp_path / "c")


def test_parallel_build_writes_the_same_bytes(tmp_path):
    """Two worker processes build the same files as one (every item is a pure function of its seeds)."""
    import hashlib

    def digest(root):
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file()}

    serial = build_split(TINY, tmp_path / "one")
    said = []
    parallel = build_split(TINY, tmp_path / "two", progress=said.append, workers=2)
    assert sorted(said) == sorted(["site 101", "site 201", "survey 101", "walk 101/w0", "survey 201", "walk 201/w0"])
    a, b = digest(serial.root), digest(parallel.root)
    assert len(a) > 10 and a == b
    with pytest.raises(ConfigError, match="workers"):
        build_split(TINY, tmp_path / "three", workers=0)


def test_later_days_split_tests_the_same_sites_weeks_later(tmp_path):
    """Issue 22 item 5: the same substation patrolled daily — training walks on consecutive days, test walks
    four weeks later with other seeds, walkers and hours: another sky over the same yard."""
    later = BenchmarkSplit("later", train_sites=(301,), test_sites=(301,), walks_per_site=2, walk_s=12.0,
                           cell_size_m=40.0, capture_s=1.0, later_days=True, day_gap_days=28)
    layout = build_split(later, tmp_path / "l", workers=1)
    train = [load_walk(w) for w in layout.train_walks]
    test = [load_walk(w) for w in layout.test_walks]
    assert [w.directory.name for w in train + test] == ["w0", "w1", "later0", "later1"]
    assert [(w.start_utc.date() - train[0].start_utc.date()).days for w in train + test] == [0, 1, 28, 29]
    assert len({w.start_utc.hour * 3600 + w.start_utc.minute * 60 for w in train + test}) == 4
    assert later.walk_seed(301, 0, test=True) != later.walk_seed(301, 0) and \
        later.person(301, 0, test=True) != later.person(301, 1)
    assert split_layout(tmp_path / "l").split == later

