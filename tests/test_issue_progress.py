"""Issue 12 item 17: progress on long simulations, plain lines when stderr is not a terminal."""

import io

from simulation.progress import Progress
from simulation.walk import simulate_walk


def test_plain_lines_without_a_terminal_and_a_bar_on_one():
    buf = io.StringIO()
    with Progress(10, "audio", unit="s", stream=buf, tty=False) as p:
        for _ in range(10):
            p.update(1)
    lines = buf.getvalue().splitlines()
    assert "\r" not in buf.getvalue()
    assert lines[0] == "audio: 1/10 s (10 %)" and lines[-1] == "audio: 10/10 s (100 %)" and len(lines) == 10
    quiet = io.StringIO()
    with Progress(10, "audio", stream=quiet, enabled=False) as p:
        p.update(10)
    assert quiet.getvalue() == ""
    bar = io.StringIO()
    with Progress(10, "audio", stream=bar, tty=True) as p:
        p.update(10)
    assert "\r" in bar.getvalue()


def test_simulate_walk_reports_progress(site_dir, tmp_path, capfd):
    simulate_walk(site_dir, tmp_path / "w", seed=2, duration_s=5.0,
                  writers=("simulation.gnss.stream:write_gnss", "simulation.imu.stream:write_imu"))
    err = capfd.readouterr().err
    assert "'w': streams written: 1/2" in err and "'w': streams written: 2/2" in err and "\r" not in err
    simulate_walk(site_dir, tmp_path / "q", seed=2, duration_s=5.0, progress=False,
                  writers=("simulation.gnss.stream:write_gnss",))
    assert capfd.readouterr().err == ""
