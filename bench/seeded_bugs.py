"""Seeded realistic bugs (issue 20): for each, the test that kills it.

Each bug is one exact text replacement in one source file. For every bug the tree is copied (the files git
knows of, tracked and untracked-but-not-ignored: no ``.git``, ``.venv`` or caches) into a fresh temporary
directory, the replacement is applied — and the run stops with an error if the text to replace does not
occur exactly once, so a bug can never be reported killed because its mutation did not apply — and the
named tests run there::

    PYTHONPATH=<copy> python -m pytest -q -x -p no:cacheprovider <tests>     (cwd = the copy)

KILLED means pytest exited 1 with at least one failed test case in its JUnit XML; SURVIVED means the tests
passed on the mutant; anything else (collection error, timeout, no tests) is ERROR and counts as neither.
The same tests run once on an unmutated copy (once per distinct test list): a test that fails there does
not count as killing, and the bug is reported as not demonstrated.

Usage::

    python bench/seeded_bugs.py [--tree DIR] [--only 1,4b] [--json out.json] [--python PY]

It runs one pytest at a time (``-p no:xdist``); about 6–10 min on two shared cores.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_PYTHON = "/work/main/.venv/bin/python"
TIMEOUT_S = 900

MR = "tests/test_method_registry.py::test_metric_rows_by_hand"
MR_LO = "tests/test_method_registry.py::test_nees_in_bounds_counts_the_lower_tail_by_hand"


@dataclass(frozen=True)
class Bug:
    """One seeded bug: replace ``old`` (must occur exactly once in ``path``) by ``new``."""

    key: str
    what: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]


BUGS = [
    Bug("1", "NEES e'Pe instead of e'P⁻¹e (metric rows)", "walks/score.py",
        'np.einsum("ni,nij,nj->n", e[good], np.linalg.inv(c[good]), e[good])',
        'np.einsum("ni,nij,nj->n", e[good], c[good], e[good])', (MR,)),
    Bug("1b", "NEES e'Pe instead of e'P⁻¹e (consistency.nees)", "models/fusion/consistency.py",
        'np.einsum("mi,mi->m", e, np.linalg.solve(Pd, e[..., None])[..., 0])',
        'np.einsum("mi,mi->m", e, (Pd @ e[..., None])[..., 0])',
        ("models/fusion/consistency.py", "tests/test_filters.py::test_nees_in_bounds_share_monte_carlo")),
    Bug("2", "p95_m holds the median", "walks/score.py",
        '"p95_m": float(np.percentile(x, 95))', '"p95_m": float(np.median(x))', (MR,)),
    Bug("3", "per-class metric rows shifted by one class", "walks/score.py",
        "[(c, cls == k) for k, c in enumerate(ENV_CLASSES)]",
        "[(c, cls == k) for k, c in enumerate(ENV_CLASSES, 1)]", (MR,)),
    Bug("4", "kf_map lookup with east and north swapped (ClassMap)", "models/fusion/events.py",
        "    def __call__(self, east_m: float, north_m: float) -> int:",
        "    def __call__(self, north_m: float, east_m: float) -> int:",
        ("tests/test_issue_map_orientation.py",)),
    Bug("4b", "kf_map lookup with east and north swapped (filter core's map_class call)", "models/fusion/core.py",
        "map_class(map_grid, map_geo, x[0], x[1])", "map_class(map_grid, map_geo, x[1], x[0])",
        ("tests/test_issue_map_orientation.py",)),
    Bug("5", "per-class GNSS white variance s² without its /2 (ContextNoise cell)", "models/fusion/context.py",
        "ud.append(_mahalanobis2(d, s.cov_m2[1:][pair] + s.cov_m2[:-1][pair]) / 2.0)",
        "ud.append(_mahalanobis2(d, s.cov_m2[1:][pair] + s.cov_m2[:-1][pair]))",
        ("tests/test_issue_noise_variances.py",)),
    Bug("5b", "per-axis GNSS variance (UERE·HDOP)² without its /2 (QualityNoise)", "models/fusion/noise.py",
        "var = (uere * h) ** 2 / 2.0", "var = (uere * h) ** 2",
        ("tests/test_issue_noise_variances.py",)),
    Bug("5c", "per-class R as the sample covariance (mean removed, n − 1) instead of E[ee']", "models/fusion/noise.py",
        "    r = e.T @ e / max(len(e), 1)", "    r = np.cov(e.T)",
        ("tests/test_issue_noise_variances.py",)),
    Bug("6", "BP training target sign flipped (filter − truth)", "training/filters.py",
        "y = np.stack([te - run.x[:, 0], tn - run.x[:, 1]], axis=1)",
        "y = np.stack([run.x[:, 0] - te, run.x[:, 1] - tn], axis=1)",
        ("tests/test_issue_bp_inputs.py::test_bp_targets_are_truth_minus_the_filter",)),
    Bug("7", "BP guard fed the posterior instead of the prior", "walks/methods.py",
        "bp.correct(X, run.x_prior[:, :2],", "bp.correct(X, run.x[:, :2],",
        ("tests/test_issue_bp_inputs.py::test_the_adaptive_guard_is_fed_the_prior",)),
    Bug("8", "Kalman update: the Joseph branch uses the short form P = (I − KH)P⁻", "models/fusion/core.py",
        "        Pn = P - KHP - KHP.T + mmt(mm(K, S), K)\n", "        Pn = P - KHP\n",
        ("tests/test_filters.py::test_update_matches_filterpy_with_an_ill_conditioned_prior",
         "tests/test_filters.py::test_update_matches_filterpy_joseph_form")),
    Bug("8b", "Kalman update: Joseph form without the K R K' term", "models/fusion/core.py",
        "        Pn = P - KHP - KHP.T + mmt(mm(K, S), K)\n", "        Pn = P - KHP - KHP.T + mmt(mm(K, HPH), K)\n",
        ("tests/test_filters.py::test_update_matches_filterpy_with_an_ill_conditioned_prior",
         "tests/test_filters.py::test_update_matches_filterpy_joseph_form")),
    Bug("9", "DPC centre rule γ = ρ + δ instead of ρ·δ", "models/dpc.py",
        "    gamma = rho * delta\n", "    gamma = rho + delta\n",
        ("tests/test_dpc.py::test_centre_rule_is_rho_times_delta_where_rho_plus_delta_disagrees",)),
    Bug("10", "severity sign of the Rician K flipped", "models/embedding.py",
        '"rician_k_db": -1.0,', '"rician_k_db": 1.0,',
        ("tests/test_embedding.py::test_severity_direction_is_hard_coded_per_feature",
         "tests/test_embedding.py::test_severity_of_a_blocked_cluster_by_hand")),
    Bug("10b", "severity sign of the DOP growth flipped", "models/embedding.py",
        '"dop_growth": 1.0,', '"dop_growth": -1.0,',
        ("tests/test_embedding.py::test_severity_direction_is_hard_coded_per_feature",)),
    Bug("11", "logistic class weights dropped", "models/environment.py",
        "LogisticRegression(C=self.C, max_iter=2000, class_weight=self.class_weight)",
        "LogisticRegression(C=self.C, max_iter=2000, class_weight=None)",
        ("tests/test_environment_classifier.py::test_class_weights_balance_an_imbalanced_library",
         "tests/test_environment_classifier.py::test_class_weights_equal_hand_computed_sample_weights")),
    Bug("12", "has_capture compares parameters as JSON text without sort_keys", "fingerprints/library.py",
        "    return stored == json.loads(json.dumps(dict(params)))\n",
        "    return stored_json == json.dumps(dict(params))\n",
        ("tests/test_fingerprint_library.py::test_feature_parameters_compare_as_json_objects_not_text",)),
    Bug("13", "Dask results gathered in completion order", "pipeline/parallel.py",
        "            i = index[fut.key]\n", "            i = out.index(None)\n",
        ("tests/test_parallel.py::test_dask_results_keep_the_input_order_when_later_walks_finish_first",)),
    Bug("14", "nees_in_bounds one-sided (upper 7.38 only, metric rows)", "walks/score.py",
        "float(np.mean((v[fin] >= lo) & (v[fin] <= hi)))", "float(np.mean(v[fin] <= hi))", (MR, MR_LO)),
    Bug("14b", "in_bounds_share one-sided (upper bound only, consistency)", "models/fusion/consistency.py",
        "    return float(np.mean((eps[ok] >= lo) & (eps[ok] <= hi)))",
        "    return float(np.mean(eps[ok] <= hi))",
        ("tests/test_filters.py::test_nees_in_bounds_share_monte_carlo",
         "tests/test_filters.py::test_in_bounds_share_counts_both_tails_by_hand")),
]


class MutationNotApplied(RuntimeError):
    """The text a bug replaces is absent (or not unique): the table would lie, so the run stops."""


def tree_files(tree: Path) -> list[str]:
    """Files git knows of in ``tree`` (tracked, and untracked but not ignored), that exist on disk."""
    out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=tree, check=True,
                         capture_output=True).stdout.decode().split("\0")
    return [f for f in out if f and (tree / f).is_file()]


def copy_tree(tree: Path, files: list[str], dest: Path) -> None:
    for f in files:
        (dest / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(tree / f, dest / f)


def apply(bug: Bug, root: Path) -> None:
    p = root / bug.path
    text = p.read_text()
    n = text.count(bug.old)
    if n != 1:
        raise MutationNotApplied(f"bug {bug.key}: {bug.path} holds the text to replace {n} times (need 1): "
                                 f"{bug.old!r}")
    p.write_text(text.replace(bug.old, bug.new))


def run_tests(python: str, root: Path, tests: tuple[str, ...]) -> dict:
    """pytest in ``root``: return code, wall time, failed test ids (JUnit XML), counts, the tail of stdout."""
    xml = root / "_junit.xml"
    env = {**os.environ, "PYTHONPATH": str(root), "PYTHONDONTWRITEBYTECODE": "1"}
    t0 = time.perf_counter()
    try:
        r = subprocess.run([python, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-p", "no:xdist",
                            f"--junitxml={xml}", *tests], cwd=root, env=env, capture_output=True, text=True,
                           timeout=TIMEOUT_S)
        rc, out = r.returncode, r.stdout + r.stderr
    except subprocess.TimeoutExpired:
        rc, out = -1, f"timeout after {TIMEOUT_S} s"
    wall = time.perf_counter() - t0
    failed, passed = [], 0
    if xml.exists():
        for case in ET.parse(xml).iter("testcase"):
            name = f"{case.get('classname')}::{case.get('name')}"
            if case.find("failure") is not None or case.find("error") is not None:
                failed.append(name)
            elif case.find("skipped") is None:
                passed += 1
    return {"rc": rc, "wall_s": round(wall, 1), "failed": failed, "passed": passed,
            "tail": "\n".join(out.strip().splitlines()[-3:])}


def verdict(res: dict) -> str:
    if res["rc"] == 1 and res["failed"]:
        return "KILLED"
    if res["rc"] == 0 and res["passed"] > 0:
        return "SURVIVED"
    return f"ERROR (rc {res['rc']})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=REPO, help="the source tree under test (a git work tree)")
    ap.add_argument("--python", default=DEFAULT_PYTHON if Path(DEFAULT_PYTHON).exists() else sys.executable)
    ap.add_argument("--only", default="", help="comma-separated bug keys (default: all)")
    ap.add_argument("--json", type=Path, help="write the per-bug results here")
    a = ap.parse_args(argv)
    bugs = [b for b in BUGS if not a.only or b.key in a.only.split(",")]
    tree = a.tree.resolve()
    files = tree_files(tree)
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="seeded_bugs_") as tmp:
        tmp = Path(tmp)
        # every mutation must apply before anything runs
        for b in bugs:
            d = tmp / f"check_{b.key}"
            (d / b.path).parent.mkdir(parents=True)
            shutil.copy2(tree / b.path, d / b.path)
            apply(b, d)
        baseline = {}
        rows = []
        for b in bugs:
            if b.tests not in baseline:
                d = tmp / f"clean_{len(baseline)}"
                copy_tree(tree, files, d)
                baseline[b.tests] = run_tests(a.python, d, b.tests)
                print(f"[unmutated] {' '.join(b.tests)}: rc {baseline[b.tests]['rc']}, "
                      f"{baseline[b.tests]['wall_s']} s", file=sys.stderr, flush=True)
            base = baseline[b.tests]
            d = tmp / f"bug_{b.key}"
            copy_tree(tree, files, d)
            apply(b, d)
            res = run_tests(a.python, d, b.tests)
            v = verdict(res)
            clean_ok = base["rc"] == 0 and base["passed"] > 0
            if v == "KILLED" and not clean_ok:
                v = "NOT SHOWN (tests fail unmutated)"
            rows.append({"bug": b.key, "what": b.what, "file": b.path, "old": b.old.strip(), "new": b.new.strip(),
                         "tests": list(b.tests), "verdict": v, "killed_by": res["failed"],
                         "unmutated_pass": clean_ok, "unmutated": base, "mutant": res})
            print(f"[bug {b.key}] {v} in {res['wall_s']} s {res['failed'][:1]}", file=sys.stderr, flush=True)
            shutil.rmtree(d, ignore_errors=True)
    total = time.perf_counter() - t_start
    print("| bug | seeded bug | file | replacement | test(s) | mutant | unmutated |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        tests = "<br>".join(t.replace("tests/", "") for t in r["tests"])
        repl = f"`{r['old']}` → `{r['new']}`".replace("|", "\\|")
        print(f"| {r['bug']} | {r['what']} | {r['file']} | {repl} | {tests} | {r['verdict']} | "
              f"{'pass' if r['unmutated_pass'] else 'FAIL'} |")
    n_killed = sum(r["verdict"] == "KILLED" for r in rows)
    print(f"\n{n_killed} of {len(rows)} seeded bugs killed; {total:.0f} s in all.")
    if a.json:
        tmpj = a.json.with_suffix(a.json.suffix + ".tmp")
        tmpj.write_text(json.dumps({"tree": str(tree), "runtime_s": round(total, 1), "bugs": rows}, indent=1))
        os.replace(tmpj, a.json)
    return 0 if n_killed == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
