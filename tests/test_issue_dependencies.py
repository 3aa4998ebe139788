"""Issue 12 item 27: what the packages import is declared, and nothing unused is a runtime dependency.

``ahrs`` was a runtime dependency nothing imported; ``imufusion`` was imported (by ``imufusion_heading``)
but declared nowhere. Both are now the optional extra ``compare``.
"""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("features", "simulation", "fingerprints", "models", "walks", "training", "pipeline")
IMPORT_NAME = {"scikit-learn": "sklearn", "tomli-w": "tomli_w", "pytest-xdist": "xdist",
               "import-linter": "importlinter", "opentsne": "openTSNE"}


def _declared():
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]

    def names(reqs):
        out = set()
        for r in reqs:
            dist = re.match(r"[A-Za-z0-9_.\-]+", r).group(0).lower()
            out.add(IMPORT_NAME.get(dist, dist.replace("-", "_")))
        return out

    return names(meta["dependencies"]), {k: names(v) for k, v in meta["optional-dependencies"].items()}


def _imports(roots):
    found = set()
    for root in roots:
        for f in (REPO / root).rglob("*.py"):
            for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Import):
                    found.update(a.name.split(".")[0] for a in node.names)
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    found.add(node.module.split(".")[0])
    # tests and bench import their own sibling modules (tests.conftest, bench.smartloc): not third-party packages.
    return {m for m in found if m not in sys.stdlib_module_names and m not in PACKAGES and m not in ("tests", "bench")}


def test_every_package_import_is_declared():
    runtime, extras = _declared()
    undeclared = _imports(PACKAGES) - runtime - set().union(*extras.values())
    assert undeclared == set()


def test_runtime_dependencies_are_imported_by_the_packages():
    runtime, _ = _declared()
    assert runtime - _imports(PACKAGES) == set()
    assert "ahrs" not in runtime and "imufusion" not in runtime
    # issue 19: filterpy is the tests' reference, imported by no product module
    assert "filterpy" not in runtime and "filterpy" not in _imports(PACKAGES)
    # issue 27: hmmlearn is the class HMM tests' reference, imported by no product module
    assert "hmmlearn" not in runtime and "hmmlearn" not in _imports(PACKAGES)


def test_comparison_yardsticks_are_an_optional_extra():
    _, extras = _declared()
    assert {"imufusion", "ahrs"} <= extras["compare"]
    local = {f.stem for f in (REPO / "bench").glob("*.py")}                              # bench's own helpers
    assert _imports(["bench"]) - local - _declared()[0] - set().union(*extras.values()) == set()   # bench too


def test_imufusion_heading_without_the_extra_is_a_clean_error(monkeypatch):
    import numpy as np

    from features.errors import ConfigError
    from features.imu.heading import imufusion_heading

    monkeypatch.setitem(sys.modules, "imufusion", None)   # import fails as if not installed
    z = np.zeros((3, 3))
    with pytest.raises(ConfigError, match=r'optional extra "compare"'):
        imufusion_heading(z, z, z, 100.0)
