"""Warm workers (issue 25, item 4): ``evaluate`` reads the model once per process, keeps it across walks and,
on a long-lived Dask cluster (``--scheduler``), across runs, and reads it again when its folder was replaced."""

from __future__ import annotations

import os
import shutil

import pytest

import models.fusion.model as fusion_model
from models.bundle import BundleError
from models.fusion.model import load_fusion_model, save_fusion_model
from pipeline.evaluate import evaluate, load_model, model_loads


@pytest.fixture
def counted(monkeypatch):
    """Every read of a fusion bundle through :func:`pipeline.evaluate.load_model`, by folder name."""
    calls: list[str] = []
    real = fusion_model.load_fusion_model

    def counting(path):
        calls.append(os.path.basename(str(path)))
        return real(path)

    monkeypatch.setattr(fusion_model, "load_fusion_model", counting)
    return calls


def _replace_with_marked_copy(model_dir, tmp_path, marker: str) -> None:
    """Replace ``model_dir`` by another model (its meta carries ``marker``), as a user swapping the folder with
    ``rsync -a`` or ``cp -p`` would: every file keeps the old one's modification time."""
    times = {f.name: f.stat() for f in model_dir.iterdir()}
    model = load_fusion_model(model_dir)
    model.meta = {**model.meta, "marker": marker}
    staged = tmp_path / f"staged_{marker}"
    save_fusion_model(model, staged)
    shutil.rmtree(model_dir)
    shutil.copytree(staged, model_dir)
    for f in model_dir.iterdir():
        st = times.get(f.name, times["bundle.json"])
        os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_a_two_walk_evaluate_reads_the_model_once_and_the_next_run_not_at_all(bad_input_world, tmp_path, counted):
    W = bad_input_world
    fm = tmp_path / "fm"                                 # a path this process has never loaded
    shutil.copytree(W.fm, fm)
    before = model_loads()
    out = evaluate([W.w, W.w2], fm, tmp_path / "r1", methods=("kf",), workers=1, progress=False, plots=False)
    assert len(out["results"]) == 2 and not out["failures"]
    # the validation before the walks reads it; the two walks reuse it (a reload per walk would make this 3)
    assert counted == ["fm"] and model_loads() - before == 1
    evaluate([W.w2], fm, tmp_path / "r2", methods=("kf",), workers=1, progress=False, plots=False)
    assert counted == ["fm"]


def test_a_replaced_model_folder_is_not_served_stale(bad_input_world, tmp_path, counted):
    W = bad_input_world
    fm = tmp_path / "fm"
    shutil.copytree(W.fm, fm)
    assert "marker" not in load_model(fm).meta
    _replace_with_marked_copy(fm, tmp_path, "B")
    assert (fm / "bundle.json").stat().st_mtime_ns == (W.fm / "bundle.json").stat().st_mtime_ns
    assert load_model(fm).meta["marker"] == "B"          # same path, same times, new content: read again
    assert load_model(fm).meta["marker"] == "B" and counted == ["fm", "fm"]     # and kept from then on
    shutil.rmtree(fm)
    with pytest.raises(BundleError, match="not a model directory"):  # gone: the cached one is not served
        load_model(fm)


def test_a_long_lived_cluster_keeps_its_model_across_runs_until_the_folder_changes(bad_input_world, tmp_path):
    """``evaluate --scheduler`` on one single-threaded worker: two runs of two walks read the model once on the
    worker; after the folder is replaced (same times, new content) the next run reads it once more."""
    import logging

    from distributed import Client, LocalCluster

    W = bad_input_world
    fm = tmp_path / "fm"
    shutil.copytree(W.fm, fm)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        def loads_on_worker() -> int:
            return next(iter(client.run(model_loads).values()))

        for k in range(2):
            out = evaluate([W.w, W.w2], fm, tmp_path / f"r{k}", methods=("kf",), scheduler=cluster.scheduler_address,
                           progress=False, plots=False)
            assert len(out["results"]) == 2 and not out["failures"]
            assert loads_on_worker() == 1
        _replace_with_marked_copy(fm, tmp_path, "C")
        evaluate([W.w2], fm, tmp_path / "r3", methods=("kf",), scheduler=cluster.scheduler_address, progress=False,
                 plots=False)
        assert loads_on_worker() == 2
        marker = client.submit(lambda p: load_model(p).meta.get("marker"), str(fm), pure=False).result()
        assert marker == "C" and loads_on_worker() == 2


def test_local_workers_are_forked_on_linux_unless_the_user_chose_dask_s_start_method(monkeypatch):
    """Forked workers start with this process's imports and checked model; a user's DASK_... setting stands."""
    import sys

    from pipeline.parallel import local_worker_config

    monkeypatch.delenv("DASK_DISTRIBUTED__WORKER__MULTIPROCESSING_METHOD", raising=False)
    method = local_worker_config()["distributed.worker.multiprocessing-method"]
    assert method == ("fork" if sys.platform.startswith("linux") else "spawn")
    monkeypatch.setenv("DASK_DISTRIBUTED__WORKER__MULTIPROCESSING_METHOD", "spawn")
    assert "distributed.worker.multiprocessing-method" not in local_worker_config()


def _worker_profiler_setting(walk):
    import dask
    from distributed import get_worker

    return dask.config.get("distributed.worker.profile.enabled"), get_worker().name is not None


def test_local_workers_run_without_dask_s_statistical_profiler():
    """The profiler samples a worker's stack every 10 ms for a dashboard nobody is served: 2-5 % of a walk's time
    on two workers (pipeline.parallel._LOCAL_WORKER_CONFIG). Checked where it counts, on the workers."""
    from pipeline.parallel import map_walks

    out = map_walks(_worker_profiler_setting, ["a", "b"], workers=2, progress=False)
    assert out == [(False, True), (False, True)]
