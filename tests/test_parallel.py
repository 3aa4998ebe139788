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


def test_longest_first_orders_by_bytes_on_disk_ties_in_input_order(tmp_path):
    """Graham's LPT rule on the walks' sizes: files by their bytes, folders by the bytes of the files in them
    (sizes worked out by hand), anything that is not on disk as 0; equal sizes keep their input order."""
    from pipeline.parallel import longest_first

    small = tmp_path / "small.bin"
    small.write_bytes(b"x" * 10)
    folder = tmp_path / "walk"
    folder.mkdir()
    (folder / "audio.wav").write_bytes(b"a" * 300)
    (folder / "gnss.nmea").write_bytes(b"g" * 50)            # folder: 350 bytes
    (folder / "sub").mkdir()                                 # a sub-folder adds nothing
    big = tmp_path / "big.bin"
    big.write_bytes(b"y" * 400)
    twin = tmp_path / "twin.bin"
    twin.write_bytes(b"z" * 10)
    walks = [small, "not-a-walk", folder, big, twin]
    assert longest_first(walks) == [3, 2, 0, 4, 1]           # 400, 350, 10, 10 (input order), 0
    assert longest_first([]) == []


def started_task(walk):
    """The walk's name, this worker's process id and when the task started (for the order of work)."""
    import os
    import time

    t0 = time.time()
    time.sleep(0.3)
    return Path(walk).name, os.getpid(), t0


def test_dask_hands_out_the_largest_walks_first_and_returns_results_in_input_order(tmp_path):
    """Six walks given smallest first: on two workers each worker takes its walks largest first and the largest
    walk starts before the smallest, yet the results come back in the input order."""
    walks = []
    for i in range(6):
        p = tmp_path / f"w{i}.bin"
        p.write_bytes(b"x" * (1000 * (i + 1)))
        walks.append(p)
    out = map_walks(started_task, walks, workers=2, progress=False)
    assert [name for name, _, _ in out] == [w.name for w in walks]          # input order
    size = {w.name: w.stat().st_size for w in walks}
    for pid in {p for _, p, _ in out}:
        mine = sorted((t0, name) for name, p, t0 in out if p == pid)
        assert [size[n] for _, n in mine] == sorted((size[n] for _, n in mine), reverse=True)
    start = {name: t0 for name, _, t0 in out}
    assert start["w5.bin"] < start["w0.bin"]


def _periodic_ms():
    """On a Dask worker: its event loop's periodic callbacks (ms) and its nanny's memory monitor interval."""
    from distributed import get_worker

    pcs = get_worker().periodic_callbacks
    return {name: pcs[name].callback_time for name in ("tick", "monitor", "memory_monitor")}


def test_local_workers_run_dask_s_periodic_callbacks_at_the_slower_pace():
    """The tick, the system monitor and the memory monitor at 1 s, 5 s and 1 s (Dask's 20 ms, 500 ms, 100 ms):
    checked where they run, on the workers' event loops (pipeline.parallel._LOCAL_WORKER_CONFIG)."""
    out = map_walks(_worker_callbacks_task, ["a", "b"], workers=2, progress=False)
    assert out == [{"tick": 1000.0, "monitor": 5000.0, "memory_monitor": 1000.0}] * 2


def _worker_callbacks_task(walk):
    return _periodic_ms()


def test_a_dask_setting_the_user_chose_in_the_environment_stands(monkeypatch):
    """Each key of the local cluster's settings is left out when its DASK_... variable is set, the name being the
    one Dask itself reads (checked against dask.config.collect_env)."""
    import dask.config

    from pipeline.parallel import _LOCAL_WORKER_CONFIG, _dask_env_name, local_worker_config

    for key in [k for k in _LOCAL_WORKER_CONFIG if "pre-spawn-environ" not in k]:
        parsed = dask.config.collect_env({_dask_env_name(key): "7"})
        node = parsed
        for part in key.split("."):
            node = node[dask.config.canonical_name(part, node)]
        assert node == 7
    monkeypatch.delenv("DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL", raising=False)
    assert local_worker_config()["distributed.admin.tick.interval"] == "1s"
    monkeypatch.setenv("DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL", "20ms")
    cfg = local_worker_config()
    assert "distributed.admin.tick.interval" not in cfg and cfg["distributed.worker.memory.monitor-interval"] == "1s"
    # a worker's environment variable is set as itself (MALLOC_TRIM_THRESHOLD_, test above), never through DASK_...
    monkeypatch.setenv("DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON__MALLOC_TRIM_THRESHOLD_", "1")
    assert local_worker_config()["distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"] is None


def reporting_task(walk, parts: int):
    """Tells its progress ``parts`` times, 50 ms apart (two such tasks on a two-thread worker overlap)."""
    import time

    from pipeline.parallel import task_progress

    for k in range(1, parts + 1):
        time.sleep(0.05)
        task_progress(k, parts)
    return Path(walk).name


def test_progress_of_tasks_running_at_once_on_one_worker_goes_to_their_own_walks(tmp_path, capsys):
    """A long-lived cluster whose worker runs two tasks at once (``--scheduler``; threads_per_worker=2), used by
    two runs one after the other: each walk's progress lines name that walk, once per part, each run's only its
    own walks (a report kept per process rather than per thread sent one walk's parts as the other's)."""
    from distributed import LocalCluster

    walks = []
    for i in range(2):
        walks.append(tmp_path / f"walk{i}")
        walks[-1].write_bytes(b"x" * (10 + i))
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None) as cluster:
        for run in range(2):
            assert map_walks(reporting_task, walks, 4, scheduler=cluster.scheduler_address, desc="t") == \
                ["walk0", "walk1"]
            lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("t:")]
            parts = [f"t: walk{i}: {k}/4 segments ({25 * k} %)" for i in range(2) for k in range(1, 5)]
            assert sorted(lines) == sorted(parts + ["t: 1/2 walks (50 %)", "t: 2/2 walks (100 %)"]), (run, lines)
