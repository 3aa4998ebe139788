"""The benchmark split: seeded simulated substations for training and others, held out, for testing.

Every figure envfuse reports about its models comes from a split defined here:
training sites (their surveys build the fingerprint library, their walks fit
the fusion model) and test sites with other seeds — so other layouts, other
beacon plans, other start times and so other constellations, other walkers —
that nothing is fitted or tuned on. A split is data, not code paths: its
seeds and sizes are listed in :data:`SPLITS` and written to ``split.toml``
beside what it builds, so a run can always be traced to its inputs.

It lives in ``simulation`` because building a split is simulating; what
fits and evaluates on it (``training``, ``walks``) reads the files the split
wrote, exactly as it would read a real survey and real walk logs.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from datetime import timedelta
from pathlib import Path
from typing import Callable

from features.errors import ConfigError
from features.fileio import read_toml, write_toml

__all__ = ["BenchmarkSplit", "SPLITS", "SplitLayout", "build_split", "split_layout"]


@dataclass(frozen=True)
class BenchmarkSplit:
    """Seeds and sizes of one split.

    ``train_sites`` / ``test_sites`` are site seeds; each site gets a survey
    (``cell_size_m`` cells, ``capture_s`` each) and ``walks_per_site`` walks of
    ``walk_s`` seconds. Walk seeds are ``1000·site + k`` and walkers (person
    seeds) ``site·10 + k``, so no walker of a test site walked a training site.

    ``later_days``: the other honest split — the same substations patrolled
    daily (the deployment of one surveyed site, and the setting of the seed
    paper's experiment). Training and test sites are then the same; each site's
    training walks are on consecutive days from a day drawn from the site's
    seed, its test walks (other seeds 1000·site + 500 + k, other walkers) start
    ``day_gap_days`` later, at other hours: another sky over the same yard.
    Otherwise the sites must be disjoint (leave-site-out).
    """

    name: str
    train_sites: tuple[int, ...]
    test_sites: tuple[int, ...]
    walks_per_site: int = 2
    walk_s: float = 300.0
    cell_size_m: float = 10.0
    capture_s: float = 10.0
    later_days: bool = False
    day_gap_days: int = 28

    def __post_init__(self):
        if not self.train_sites or not self.test_sites:
            raise ConfigError(f"split {self.name!r}: needs at least one training and one test site")
        if self.later_days:
            if tuple(self.train_sites) != tuple(self.test_sites):
                raise ConfigError(f"split {self.name!r}: a later-days split trains and tests on the same sites")
            if self.day_gap_days < 1:
                raise ConfigError(f"split {self.name!r}: day_gap_days must be >= 1, got {self.day_gap_days}")
        elif set(self.train_sites) & set(self.test_sites):
            raise ConfigError(f"split {self.name!r}: sites {sorted(set(self.train_sites) & set(self.test_sites))} "
                              "are both training and test sites")
        if self.walks_per_site < 1:
            raise ConfigError(f"split {self.name!r}: walks_per_site must be >= 1, got {self.walks_per_site}")
        for key in ("walk_s", "cell_size_m", "capture_s"):
            if not getattr(self, key) > 0:
                raise ConfigError(f"split {self.name!r}: {key} must be positive, got {getattr(self, key)}")

    def walk_seed(self, site: int, k: int, test: bool = False) -> int:
        return 1000 * site + (500 if test and self.later_days else 0) + k

    def person(self, site: int, k: int, test: bool = False) -> int:
        return 10 * site + (5 if test and self.later_days else 0) + k

    def walk_start(self, site: int, k: int, test: bool = False):
        """The walk's start (UTC): on a later-days split, training walk k on the site's first day + k, test walk
        k ``day_gap_days`` later, each at an hour from its own seed; otherwise None (the simulator's seeded
        default)."""
        if not self.later_days:
            return None
        from simulation.rng import stream_rng
        from simulation.walk import DEFAULT_EPOCH_UTC

        day0 = int(stream_rng(site, "split-first-day").integers(0, 300))
        day = day0 + k + (self.day_gap_days if test else 0)
        second = int(stream_rng(self.walk_seed(site, k, test), "split-hour").integers(0, 86_400 // 10)) * 10
        return DEFAULT_EPOCH_UTC + timedelta(days=day, seconds=second)


SPLITS = {
    "demo": BenchmarkSplit("demo", train_sites=(101, 102), test_sites=(201,), walks_per_site=2, walk_s=90.0,
                           cell_size_m=12.0, capture_s=4.0),
    "standard": BenchmarkSplit("standard", train_sites=(101, 102, 103, 104, 105, 106),
                               test_sites=(201, 202, 203, 204, 205), walks_per_site=3, walk_s=300.0,
                               cell_size_m=10.0, capture_s=10.0),
    "quick": BenchmarkSplit("quick", train_sites=(101, 102, 103), test_sites=(201, 202, 203), walks_per_site=2,
                            walk_s=180.0, cell_size_m=10.0, capture_s=6.0),
    "later_days": BenchmarkSplit("later_days", train_sites=(301, 302, 303, 304, 305),
                                 test_sites=(301, 302, 303, 304, 305), walks_per_site=3, walk_s=300.0,
                                 cell_size_m=10.0, capture_s=10.0, later_days=True),
}
"""The documented splits: ``demo`` (a few minutes on 2 cores, for ``make demo``), ``quick`` (three and
three sites, about half an hour), ``standard`` (the figures in issue notes: six training sites, five
held-out test sites) and ``later_days`` (five sites, three training walks each and three test walks four
weeks later)."""


@dataclass(frozen=True)
class SplitLayout:
    """Where a built split's files are: ``root/split.toml``, ``root/sites/<seed>/site.toml``,
    ``root/surveys/<seed>/``, ``root/walks/<seed>/w<k>/``."""

    root: Path
    split: BenchmarkSplit

    def site_dir(self, site: int) -> Path:
        return self.root / "sites" / str(site)

    def survey_dir(self, site: int) -> Path:
        return self.root / "surveys" / str(site)

    def walk_dir(self, site: int, k: int, test: bool = False) -> Path:
        """``walks/<site>/w<k>``; a later-days split's test walks are ``walks/<site>/later<k>``."""
        return self.root / "walks" / str(site) / (f"later{k}" if test and self.split.later_days else f"w{k}")

    def walks(self, sites, test: bool = False) -> list[Path]:
        return [self.walk_dir(s, k, test) for s in sites for k in range(self.split.walks_per_site)]

    @property
    def train_walks(self) -> list[Path]:
        return self.walks(self.split.train_sites)

    @property
    def test_walks(self) -> list[Path]:
        return self.walks(self.split.test_sites, test=True)


def split_layout(root: str | os.PathLike) -> SplitLayout:
    """The layout of a split built in ``root`` (reads its ``split.toml``)."""
    root = Path(root)
    data = read_toml(root / "split.toml")
    try:
        split = BenchmarkSplit(name=str(data["name"]), train_sites=tuple(int(s) for s in data["train_sites"]),
                               test_sites=tuple(int(s) for s in data["test_sites"]),
                               walks_per_site=int(data["walks_per_site"]), walk_s=float(data["walk_s"]),
                               cell_size_m=float(data["cell_size_m"]), capture_s=float(data["capture_s"]),
                               later_days=bool(data.get("later_days", False)),
                               day_gap_days=int(data.get("day_gap_days", 28)))
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{root / 'split.toml'}: malformed ({exc})") from None
    return SplitLayout(root, split)


def build_split(split: BenchmarkSplit | str, root: str | os.PathLike,
                progress: Callable[[str], None] | None = None, walks: bool = True, workers: int = 1) -> SplitLayout:
    """Simulate every site, survey and walk of ``split`` into ``root``; what already exists is kept.

    Each site, survey and walk is written atomically by the simulator, so an
    interrupted build resumes where it stopped: a directory that exists is
    complete. ``progress`` receives one line per item built; ``walks=False`` builds sites and surveys only
    (an environment-model study needs no walks). ``workers`` > 1 simulates the surveys and walks in that
    many processes (sites first, serially); every item is a pure function of its seeds, so the files are
    the same bytes whatever the number of workers.
    """
    from features.site import save_site
    from simulation.site.layout import generate_site

    if isinstance(split, str):
        if split not in SPLITS:
            raise ConfigError(f"unknown split {split!r}; choose one of {sorted(SPLITS)}")
        split = SPLITS[split]
    if workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    doc = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(split).items()}
    if (root / "split.toml").is_file():
        if split_layout(root).split != split:        # (a split.toml of an older version lacks the newer defaults)
            raise ConfigError(f"{root} holds another split (its split.toml differs); choose an empty directory")
    else:
        write_toml(root / "split.toml", doc)
    layout = SplitLayout(root, split)
    say = progress or (lambda line: None)
    tasks = []
    roles = [(s, False) for s in split.train_sites] + [(s, True) for s in split.test_sites]
    for site, test in roles:
        sdir = layout.site_dir(site)
        if not (sdir / "site.toml").is_file():
            sdir.mkdir(parents=True, exist_ok=True)
            save_site(generate_site(site), sdir / "site.toml")
            say(f"site {site}")
        if not layout.survey_dir(site).is_dir() and not any(t[2] == str(layout.survey_dir(site)) for t in tasks):
            layout.survey_dir(site).parent.mkdir(parents=True, exist_ok=True)
            tasks.append(("survey", str(sdir), str(layout.survey_dir(site)), site, split.cell_size_m,
                          split.capture_s, None, f"survey {site}"))
        for k in range(split.walks_per_site if walks else 0):
            wdir = layout.walk_dir(site, k, test)
            if not wdir.is_dir():
                wdir.parent.mkdir(parents=True, exist_ok=True)
                tasks.append(("walk", str(sdir), str(wdir), split.walk_seed(site, k, test), split.walk_s,
                              split.person(site, k, test), split.walk_start(site, k, test),
                              f"walk {site}/{wdir.name}"))
    if workers == 1 or len(tasks) <= 1:
        for task in tasks:
            say(_simulate_item(task, progress=True))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=workers) as pool:
            for fut in as_completed([pool.submit(_simulate_item, t, False) for t in tasks]):
                say(fut.result())
    return layout


def _simulate_item(task: tuple, progress: bool) -> str:
    """One survey or walk of a split (a top-level function, so a process pool can run it)."""
    from simulation.survey import simulate_survey
    from simulation.walk import simulate_walk

    kind, site_dir, out, a, b, c, start, label = task
    if kind == "survey":
        simulate_survey(site_dir, out, seed=a, cell_size_m=b, capture_s=c, progress=False)
    else:
        simulate_walk(site_dir, out, seed=a, duration_s=b, person=c, start_utc=start, progress=progress)
    return label
