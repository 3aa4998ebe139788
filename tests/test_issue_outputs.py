"""Issue 12 items 8-11: outputs never put data at risk.

8: an existing device, FIFO or symlink is written through (never replaced by a plain file); ``--out -`` is stdout.
9: an output naming an input, or two outputs naming one file, is refused (exit 2) before anything is read.
10: SIGTERM ends a run like Ctrl-C (exit 143, no ``.partial`` left), and stale partials are removed on the next run.
11: a plot is written in the format its suffix names (PNG, PDF, SVG) or refused.
"""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from features.fileio import atomic_directory, atomic_write_text, clean_stale_temporaries
from pipeline.cli import main

DATA = Path(__file__).resolve().parent / "data"
REPO = Path(__file__).resolve().parents[1]


def _gnss(out, *extra):
    return main(["features", "gnss", str(DATA / "good.nmea"), "--out", str(out), *extra])


def test_dev_null_stays_a_device(capsys):
    assert _gnss("/dev/null") == 0
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full on this system")
def test_dev_full_is_one_clean_error_and_stays_a_device(capsys):
    assert _gnss("/dev/full") == 1
    err = capsys.readouterr().err
    assert "cannot write /dev/full" in err and len(err.strip().splitlines()) == 1
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


def test_fifo_is_written_through(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    assert _gnss(fifo) == 0
    reader.join(10)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert got and got[0].startswith(b"t_s,time_utc,att_mean_db")


def test_symlink_is_kept_and_its_target_replaced(tmp_path):
    target = tmp_path / "real.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    assert _gnss(link) == 0
    assert link.is_symlink() and target.read_text().startswith("t_s,time_utc,att_mean_db")


def test_dash_writes_the_table_to_stdout_and_the_summary_to_stderr(capsys):
    assert _gnss("-") == 0
    cap = capsys.readouterr()
    assert cap.out.startswith("t_s,time_utc,att_mean_db") and "with a fix" not in cap.out
    assert "epochs" in cap.err and "windows" in cap.err


def test_imu_steps_to_stdout(capsys):
    assert main(["features", "imu", str(DATA / "imu_good.csv"), "--out", "-"]) == 0
    cap = capsys.readouterr()
    assert cap.out.splitlines()[0].startswith("t_s,") and len(cap.out.splitlines()) == 21
    assert "20 steps" in cap.err


def test_output_over_its_own_input_is_refused(tmp_path, capsys):
    nmea = tmp_path / "x.nmea"
    nmea.write_bytes((DATA / "good.nmea").read_bytes())
    before = nmea.read_bytes()
    assert main(["features", "gnss", str(nmea), "--out", str(nmea)]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "input NMEA" in err and len(err.strip().splitlines()) == 1
    assert nmea.read_bytes() == before
    # the same file by another spelling, and through a symlink
    assert main(["features", "gnss", str(nmea), "--out", str(tmp_path / "." / "x.nmea")]) == 2
    (tmp_path / "alias").symlink_to(nmea)
    assert main(["features", "gnss", str(nmea), "--out", str(tmp_path / "alias")]) == 2
    assert nmea.read_bytes() == before


def test_two_outputs_naming_one_file_are_refused(tmp_path, capsys):
    x = tmp_path / "x.csv"
    assert _gnss(x, "--epochs", str(x)) == 2
    assert "--out and --epochs name the same file" in capsys.readouterr().err
    assert not x.exists()


def test_imu_output_over_input_is_refused(tmp_path, capsys):
    p = tmp_path / "imu.csv"
    p.write_bytes((DATA / "imu_good.csv").read_bytes())
    assert main(["features", "imu", str(p), "--out", str(p)]) == 2
    assert p.read_bytes() == (DATA / "imu_good.csv").read_bytes()


def test_simulated_walk_cannot_replace_its_site(tmp_path, capsys):
    (tmp_path / "site.toml").write_text('name = "t"\n[origin]\nlat_deg = 30.0\nlon_deg = 120.0\nalt_m = 20.0\n')
    assert main(["simulate", "walk", str(tmp_path), "--seed", "1", "--out", str(tmp_path), "--force"]) == 2
    assert "holds the input SITE" in capsys.readouterr().err
    assert (tmp_path / "site.toml").is_file()


def test_stale_partials_of_dead_writers_are_removed(tmp_path):
    out = tmp_path / "survey"
    dead = tmp_path / ".survey.999999999.abcd1234.partial"      # pid beyond any pid_max
    legacy = tmp_path / ".survey.k3j2h1g0.partial"              # written before pids were recorded
    alive = tmp_path / f".survey.{os.getpid()}.zzzz.partial"     # a writer still running: kept
    other = tmp_path / ".surveyX.999999999.abcd.partial"         # another output's: kept
    for d in (dead, legacy, alive, other):
        d.mkdir()
        (d / "big.bin").write_bytes(b"x" * 1000)
    with atomic_directory(out) as tmp:
        (tmp / "a").write_text("a")
    assert not dead.exists() and not legacy.exists() and alive.exists() and other.exists()
    stale_tmp = tmp_path / ".f.csv.999999999.q1w2.tmp"
    stale_tmp.write_text("half")
    atomic_write_text(tmp_path / "f.csv", "whole\n")
    assert not stale_tmp.exists() and (tmp_path / "f.csv").read_text() == "whole\n"
    assert clean_stale_temporaries(out) == []


def test_sigterm_during_a_survey_leaves_nothing_behind(tmp_path):
    site = tmp_path / "site"
    assert main(["simulate", "site", "--seed", "3", "--out", str(site)]) == 0
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", "simulate", "survey", str(site), "--out",
                             str(tmp_path / "survey"), "--cell-size-m", "10", "--capture-s", "30"],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300      # generous: the suite may share two cores with other work
    while not list(tmp_path.glob(".survey.*.partial")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
    if not list(tmp_path.glob(".survey.*.partial")):
        proc.kill()
        _, err = proc.communicate()
        pytest.fail(f"the survey never started (exit {proc.returncode}): {err.decode()[-500:]}")
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err.decode()       # 128 + SIGTERM, after the cleanup
    assert b"terminated (SIGTERM)" in err and b"Traceback" not in err
    assert not list(tmp_path.glob(".survey*")) and not (tmp_path / "survey").exists()


@pytest.mark.parametrize("where", ["__del__", "gc callback"])
def test_a_sigterm_landing_in_a_finalizer_still_terminates(where):
    """A SIGTERM whose handler runs inside a ``__del__`` (CI: a survey's, inside llvmlite's ``ObjectRef.__del__``)
    or a gc callback (the suite: hypothesis's): Python drops any exception raised there, so the command ran on to
    its end and exited 0. A dropped Terminated now sends the signal again, and Terminated comes out of the code
    that was interrupted within a second; the previous unraisable hook and handler are back afterwards."""
    import gc

    from pipeline.cli import Terminated, _sigterm_as_interrupt

    def signal_self(*_):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(10_000):                 # the handler runs here, inside the finalizer or callback
            pass

    class Finalized:
        def __del__(self):
            signal_self()

    fired = []

    def callback(phase, info):                  # once: gc.collect() runs the callbacks at its start and end
        if phase == "start" and not fired:
            fired.append(phase)
            signal_self()

    raised_at = None
    hook_before, handler_before = sys.unraisablehook, signal.getsignal(signal.SIGTERM)
    with _sigterm_as_interrupt():
        t0 = time.monotonic()
        try:
            if where == "__del__":
                obj = Finalized()
                del obj
            else:
                gc.callbacks.append(callback)
                gc.collect()
            while time.monotonic() - t0 < 3.0:
                time.sleep(0.01)
        except Terminated:
            raised_at = time.monotonic() - t0
        finally:
            if callback in gc.callbacks:
                gc.callbacks.remove(callback)
    assert raised_at is not None and raised_at < 1.0, raised_at
    assert sys.unraisablehook is hook_before and signal.getsignal(signal.SIGTERM) is handler_before


def test_plot_formats_follow_the_suffix(tmp_path):
    import matplotlib.pyplot as plt

    from pipeline.plots import save_figure

    heads = {"png": b"\x89PNG", "pdf": b"%PDF", "svg": b"<?xml"}
    for fmt, head in heads.items():
        fig, ax = plt.subplots()
        ax.plot([0, 1], [0, 1])
        p = save_figure(fig, tmp_path / f"f.{fmt.upper()}")
        assert p.read_bytes().startswith(head), fmt


def test_report_refuses_an_unknown_plot_suffix(tmp_path, capsys):
    (tmp_path / "walk.toml").write_text("")
    assert main(["report", "walk", str(tmp_path), "--out", str(tmp_path / "x.jpg")]) == 2
    err = capsys.readouterr().err
    assert ".png, .pdf or .svg" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.jpg").exists()


def test_report_walk_writes_a_real_pdf(walk_dir, tmp_path, capsys):
    out = tmp_path / "walk.pdf"
    assert main(["report", "walk", str(walk_dir), "--out", str(out)]) == 0
    assert out.read_bytes().startswith(b"%PDF")


def test_dev_stdout_redirected_to_a_file_keeps_the_table_whole(tmp_path):
    """`--out /dev/stdout > file`: the table lands whole in the file (written through the descriptor, not
    by replacing the file it resolves to), and the summary goes to stderr."""
    target = tmp_path / "redirected.csv"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    with open(target, "wb") as fh:
        res = subprocess.run([sys.executable, "-m", "pipeline", "features", "gnss", str(DATA / "good.nmea"),
                              "--out", "/dev/stdout"], cwd=REPO, env=env, stdout=fh, stderr=subprocess.PIPE,
                             timeout=120)
    assert res.returncode == 0, res.stderr.decode()
    lines = target.read_text().splitlines()
    assert lines[0].startswith("t_s,time_utc,att_mean_db") and len(lines) == 2
    assert b"epochs" in res.stderr


def test_report_plot_to_stdout(walk_dir, capsysbinary):
    assert main(["report", "walk", str(walk_dir), "--out", "-"]) == 0
    cap = capsysbinary.readouterr()
    assert cap.out.startswith(b"\x89PNG") and b"horizontal error" in cap.err


def test_check_writable_tries_the_folder_before_the_work(tmp_path):
    """(``train fusion`` fitted for minutes, then found it could not write.) A path under a file is refused with
    the option named; a new folder under a writable one passes and nothing is left behind."""
    from features.errors import EnvfuseError
    from pipeline.outputs import check_writable

    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(EnvfuseError, match=r"cannot write --out .*file/model: "):
        check_writable(blocker / "model", "--out")
    check_writable(tmp_path / "new" / "deeper" / "model", "--out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_train_fusion_writes_nothing_inside_a_training_walk(walk_dir, tmp_path, capsys):
    """As ``train env`` already did: a model folder inside one of the walks it is trained on is refused (exit 2)
    before any reading, and the walk is left as it was."""
    before = sorted(p.name for p in walk_dir.iterdir())
    code = main(["train", "fusion", "--walks", str(walk_dir), "--env-model", "default", "--no-bp",
                 "--out", str(walk_dir / "model")])
    err = capsys.readouterr().err
    assert code == 2 and "lies inside the input --walks" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in walk_dir.iterdir()) == before
