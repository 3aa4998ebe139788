"""Issue 12 item 25: `make test` (plain ``pytest``) runs the packages' doctests, not only tests/."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("features", "simulation", "fingerprints", "models", "training", "pipeline")


def test_config_collects_the_packages_with_doctests():
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert set(PACKAGES) <= set(cfg["testpaths"])
    assert "--doctest-modules" in cfg["addopts"]


def test_plain_pytest_collects_doctests_of_every_package_with_examples():
    res = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:xdist",
                          "-p", "no:cacheprovider", *PACKAGES],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    items = [ln for ln in res.stdout.splitlines() if "::" in ln]
    assert len(items) >= 60                         # 69 when this test was written
    for module in ("features/imu/reader.py", "features/gnss/quirks.py", "pipeline/args.py",
                   "simulation/site/layout.py"):
        assert any(ln.startswith(module + "::") for ln in items), module
