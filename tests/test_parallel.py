"""Per-walk tasks: serial and Dask runs give identical results in input order; a bad walk is one failure."""

import hashlib
from pathlib import Path

import pytest

from features.errors import ConfigError, DataError
from pipeline.args import UsageError
from pipeline.parallel import TaskFailure, map_walks


def digest_task(walk, salt: str):
    """A pure function of a walk's files: the SHA-256 of its bytes (and a small argument)."""
    p = Path(walk)
    if not p.is_file():
        raise DataError(f"{p}: not a walk file")
    return hashlib.sha256(p.read_bytes() + salt.encode()).hexdigest()


@pytest.fixture
def walks(tmp_path):
    out = []
    for i in range(5):
        p = tmp_path / f"w{i}.bin"
        p.write_bytes(bytes([i]) * (1000 + i))
        out.append(p)
    out.insert(2, tmp_path / "missing.bin")
    return out


def test_serial_and_dask_agree(walks):
    serial = map_walks(digest_task, walks, "s", workers=1, progress=False)
    dask = map_walks(digest_task, walks, "s", workers=2, progress=False)
    assert serial == dask
    assert isinstance(serial[2], TaskFailure) and "not a walk file" in serial[2].message
    assert len({r for r in serial if isinstance(r, str)}) == 5


def slow_first_task(walk, salt: str):
    """Like :func:`digest_task`, but the earlier a walk is in the list the longer it takes (its first byte is its
    index), so on two workers the walks finish in reverse order."""
    import time

    p = Path(walk)
    time.sleep(0.25 * (5 - p.read_bytes()[0]))
    return digest_task(walk, salt)


def test_dask_results_keep_the_input_order_when_later_walks_finish_first(walks):
    """Distinct walks finishing out of order: a result list built in completion order would differ."""
    good = [w for w in walks if w.is_file()]
    serial = [digest_task(w, "o") for w in good]
    assert len(set(serial)) == len(good)                     # distinct walks, distinct results
    assert map_walks(slow_first_task, good, "o", workers=2, progress=False) == serial


def test_a_walk_that_raises_anything_is_one_named_failure(walks):
    """Not only domain errors: any exception of one walk's task (here a ZeroDivisionError) becomes a
    TaskFailure naming the walk and the error, on Dask as serially, and the other walks' results stay."""
    for workers in (1, 2):
        out = map_walks(crashing_task, walks[:3], workers=workers, progress=False)
        assert isinstance(out[1], TaskFailure) and out[1].walk == str(walks[1])
        assert "ZeroDivisionError" in out[1].message and "\n" not in out[1].message
        assert [isinstance(r, str) for r in out] == [True, False, True]


def crashing_task(walk):
    if Path(walk).name == "w1.bin":
        return 1 / 0
    return Path(walk).name


def test_bad_arguments(walks):
    with pytest.raises(ConfigError, match="--workers must be at least 1"):
        map_walks(digest_task, walks, "s", workers=0)
    import time

    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match="--scheduler"):
        map_walks(digest_task, walks, "s", scheduler="tcp://127.0.0.1:1", progress=False)
    assert time.perf_counter() - t0 < 5.0                     # a refused port fails at once, not after 10 s
    with pytest.raises(UsageError, match="--scheduler"):
        map_walks(digest_task, walks, "s", scheduler="notaurl", progress=False)
    assert map_walks(digest_task, [], "s") == []


def test_local_workers_keep_mallocs_dynamic_mmap_threshold(monkeypatch):
    """Dask's nanny would start each local worker with MALLOC_TRIM_THRESHOLD_=65536, which switches off
    glibc's dynamic mmap threshold (184,000 page faults for four walks against 1,500); map_walks starts
    them without it, and a value the user set still reaches them."""
    import os

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    names = ["MALLOC_TRIM_THRESHOLD_"] * 2
    assert map_walks(os.getenv, names, workers=2, progress=False) == [None, None]
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "131072")
    assert map_walks(os.getenv, names, workers=2, progress=False) == ["131072", "131072"]
