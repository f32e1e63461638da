"""The ObjectNav study as a config file (``calnav study configs/study.yaml``): which rows run,
on which episodes, with which goal-threshold grid.

A study row is one map configuration (segmenter x house style x map, as config overrides). A
row either tunes its own goal threshold (``agent.goal_threshold`` x
``agent.goal_min_area_cells``, ``calnav tune``'s grid) on the tuning episodes and is then
evaluated at its best point on the disjoint evaluation episodes, or takes the tuned keys of an
earlier row (``threshold_from``): the transfer rows (a threshold tuned on clean houses applied
unchanged to scanned ones) and the agent variants evaluated at another row's threshold.

Everything here is checked when the file is loaded -- keys, ranges, row names, references,
every row's tuning and evaluation config -- so a bad study is one line before any row runs.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from calnav.common.ranges import Range, check_ranges
from calnav.envs.config import SplitName
from calnav.eval.config import Config, ConfigError, load_config, parse_override

# keys the study sets on every row itself: a row may not override them
STUDY_KEYS: tuple[str, ...] = ("env.split", "agent.goal_threshold", "agent.goal_min_area_cells", "run.agent")
STUDY_AGENT = "peanut"            # the agent whose goal detection the study tunes
TUNE_METRICS: tuple[str, ...] = ("success", "spl", "softspl")   # as eval.objectnav.tune's, higher is better
# row names become results sub-directories: letters, digits, '_', '-', '.', '@', '/'-separated parts
ROW_NAME_RE = re.compile(r"^[A-Za-z0-9_.@-]+(/[A-Za-z0-9_.@-]+)*$")
TUNE_RANGES = {
    "extend": Range(0, 10, "thresholds"),
}


def _check_episode_range(spec: str, key: str) -> range:
    """'A:B' (or 'N') -> range; malformed, empty or reversed is refused naming ``key``."""
    from calnav.envs.episodes import parse_episode_range

    try:
        return parse_episode_range(str(spec), None)
    except ValueError as exc:
        raise ValueError(f"{key}: {exc}") from None


def _check_thresholds(values: list[float], key: str) -> None:
    if not values:
        raise ValueError(f"{key} is empty; give at least one goal threshold in (0, 1]")
    bad = [v for v in values if not 0.0 < v <= 1.0]
    if bad:
        raise ValueError(f"{key}: {bad[0]} is outside (0, 1] (goal-class confidence, unitless)")


@dataclass
class TuneSection:
    """Where and how each tuned row's goal threshold is chosen."""

    split: SplitName = "val"                  # split of the tuning episodes
    episodes: str = "0:300"                   # tuning episode range of that split, A:B
    thresholds: list[float] = field(default_factory=lambda: [0.3, 0.5, 0.7, 0.9])  # goal thresholds tried, confidence in (0, 1]
    min_areas: list[int] = field(default_factory=lambda: [4])   # agent.goal_min_area_cells tried, map cells >= 1
    extend: int = 2                           # thresholds added past a grid edge the best one sits on, thresholds
    metric: str = "success"                   # what picks the best point: success | spl | softspl (higher is better)

    def __post_init__(self) -> None:
        check_ranges(self, "tune", TUNE_RANGES)
        _check_episode_range(self.episodes, "tune.episodes")
        _check_thresholds(self.thresholds, "tune.thresholds")
        if not self.min_areas or min(self.min_areas) < 1:
            raise ValueError("tune.min_areas must list integers >= 1 (map cells)")
        if self.metric not in TUNE_METRICS:
            raise ValueError(f"tune.metric {self.metric!r} is unknown; valid choices: {', '.join(TUNE_METRICS)}")


@dataclass
class EvaluateSection:
    """The held-out episodes every row is evaluated on (the same for every row: paired)."""

    split: SplitName = "test"                 # split of the evaluation episodes
    episodes: str = "0:600"                   # evaluation episode range of that split, A:B

    def __post_init__(self) -> None:
        _check_episode_range(self.episodes, "evaluate.episodes")


@dataclass
class StudyRow:
    """One row of the study: a map configuration and where its goal threshold comes from."""

    name: str                                 # row name, also its results sub-directory (e.g. learned_rgb/clean/glfs)
    overrides: list[str] = field(default_factory=list)   # config overrides of this row (dotted key=value)
    threshold_from: str = ""                  # "" = tune this row's own threshold; else an earlier tuned row's name
    thresholds: list[float] = field(default_factory=list)   # this row's tuning grid ([] = tune.thresholds)
    # "" = run this row; else why the study leaves it out (e.g. the compute budget): it does not
    # run, and the report lists it with this reason; remove the key to run it (the study resumes)
    left_out: str = ""

    def __post_init__(self) -> None:
        if not ROW_NAME_RE.match(self.name) or any(p in (".", "..") for p in self.name.split("/")):
            raise ValueError(f"row name {self.name!r} is not a relative path of letters, digits, '_', '-', '.', "
                             "'@' parts joined by '/'")
        for text in self.overrides:
            key = parse_override(text)[0]
            if key in STUDY_KEYS:
                raise ValueError(f"row {self.name}: {key} is set by the study itself (tune / evaluate sections, "
                                 "threshold_from); remove the override")
        if self.left_out != self.left_out.strip():   # blank reasons are padded too
            raise ValueError(f"row {self.name}: left_out {self.left_out!r} is blank or padded; say why the study "
                             "leaves the row out, or remove the key to run it")
        if self.thresholds:
            _check_thresholds(self.thresholds, f"row {self.name}: thresholds")
            if self.threshold_from:
                raise ValueError(f"row {self.name}: thresholds and threshold_from exclude each other "
                                 "(a row takes another's threshold or tunes its own)")


@dataclass
class StudyQuestion:
    """A question the study answers, as a contrast of rows: the per-episode sum of each row's
    metric times its weight, over the evaluation episodes all rows share (two rows weighted
    1, -1: their paired difference; four weighted 1, -1, -1, 1: a difference of differences,
    e.g. whether one map loses less than another when its threshold is transferred). The
    report's conclusions say, per question, "resolved" at 2 SEM or more, else not resolved."""

    ask: str                                  # the question, as the conclusions print it
    rows: list[str] = field(default_factory=list)        # rows of the contrast (names of rows)
    weights: list[float] = field(default_factory=list)   # one per row, summing to 0 ([] with 2 rows = [1, -1])

    def __post_init__(self) -> None:
        if not self.ask.strip():
            raise ValueError("questions: ask is empty; say what the contrast answers")
        if len(self.rows) < 2:
            raise ValueError(f"question {self.ask!r}: rows names {len(self.rows)} row(s); a contrast needs 2 or more")
        if not self.weights and len(self.rows) == 2:
            self.weights = [1.0, -1.0]
        if len(self.weights) != len(self.rows):
            raise ValueError(f"question {self.ask!r}: {len(self.weights)} weights for {len(self.rows)} rows; give one "
                             "weight per row")
        if not all(math.isfinite(w) and w != 0 for w in self.weights) or abs(sum(self.weights)) > 1e-9:
            raise ValueError(f"question {self.ask!r}: weights {self.weights} must be finite, non-zero and sum to 0 "
                             "(a comparison of rows)")


@dataclass
class StudyConfig:
    """A whole study: the base config, what every row shares, the tuning and evaluation
    episodes, and the rows in the order they run (the ones answering the main question first,
    so a study cut short has answered it)."""

    config: str = "objectnav.yaml"            # base config of every row (a file, or a name under configs/)
    overrides: list[str] = field(default_factory=list)   # overrides of every row (before the row's own)
    tune: TuneSection = field(default_factory=TuneSection)
    evaluate: EvaluateSection = field(default_factory=EvaluateSection)
    rows: list[StudyRow] = field(default_factory=list)
    # paired differences the report shows, [row, baseline] (row minus baseline on the shared
    # evaluation episodes); a transferred-threshold row is also paired with its own tuned row
    pairs: list[tuple[str, str]] = field(default_factory=list)
    questions: list[StudyQuestion] = field(default_factory=list)   # the report's conclusions, in order

    def __post_init__(self) -> None:
        if not self.rows:
            raise ValueError("rows is empty; list at least one study row")
        names = [r.name for r in self.rows]
        for q in self.questions:
            unknown = [n for n in q.rows if n not in names]
            if unknown:
                raise ValueError(f"question {q.ask!r}: {unknown[0]!r} names no row; rows: {', '.join(names)}")
            if len(set(q.rows)) != len(q.rows):
                raise ValueError(f"question {q.ask!r} names a row twice")
        for a, b in self.pairs:
            for n in (a, b):
                if n not in names:
                    raise ValueError(f"pairs: {n!r} names no row; rows: {', '.join(names)}")
            if a == b:
                raise ValueError(f"pairs: [{a}, {b}] pairs a row with itself")
        seen: dict[str, StudyRow] = {}
        for row in self.rows:
            if row.name in seen:
                raise ValueError(f"row {row.name} is listed twice; give every row its own name")
            prefix = next((n for n in seen if n.startswith(row.name + "/") or row.name.startswith(n + "/")), None)
            if prefix:   # one row's directory would hold the other's
                raise ValueError(f"row names {prefix} and {row.name} nest (one is a directory of the other); rename one")
            if row.threshold_from:
                source = seen.get(row.threshold_from)
                if source is None:
                    raise ValueError(f"row {row.name}: threshold_from {row.threshold_from!r} names no earlier row; "
                                     f"earlier rows: {', '.join(seen) or 'none'}")
                if source.threshold_from:
                    raise ValueError(f"row {row.name}: threshold_from {row.threshold_from!r} names a row that tunes "
                                     "no threshold of its own; name the row it takes its threshold from")
                if source.left_out and not row.left_out:
                    raise ValueError(f"row {row.name}: threshold_from {row.threshold_from!r} names a row the study "
                                     "leaves out; run that row too or leave this one out")
            seen[row.name] = row
        for key in ("overrides",):
            for text in getattr(self, key):
                if parse_override(text)[0] in STUDY_KEYS:
                    raise ValueError(f"{parse_override(text)[0]} is set by the study itself; remove it from overrides")
        tune, ev = self.tune, self.evaluate
        if tune.split == ev.split:
            a, b = _check_episode_range(tune.episodes, "tune.episodes"), _check_episode_range(ev.episodes, "evaluate.episodes")
            if a.start < b.stop and b.start < a.stop:
                raise ValueError(f"tune.episodes {tune.episodes} and evaluate.episodes {ev.episodes} overlap on split "
                                 f"{ev.split}: tune and evaluate on disjoint episodes")

    def row(self, name: str) -> StudyRow:
        return next(r for r in self.rows if r.name == name)

    def own_tuned(self, row: StudyRow) -> StudyRow | None:
        """The tuned row with ``row``'s overrides, for a row that takes another's threshold
        (the transfer question: the Success lost against the condition's own tuned threshold)."""
        if not row.threshold_from:
            return None
        return next((r for r in self.rows if not r.threshold_from and r.overrides == row.overrides), None)

    def row_overrides(self, row: StudyRow, extra: list[str] = ()) -> list[str]:
        """Every override of ``row`` but the study's own keys: the study's, the row's, then
        ``extra`` (the command line's, e.g. run.workers=2)."""
        return [*self.overrides, *row.overrides, *extra]

    def grid(self, row: StudyRow) -> list[float]:
        """The goal thresholds ``row`` tunes over."""
        return sorted(set(row.thresholds or self.tune.thresholds))

    def tune_overrides(self, row: StudyRow, extra: list[str] = ()) -> list[str]:
        """Overrides of ``row``'s tuning runs (``calnav tune`` adds the grid point's keys)."""
        return [*self.row_overrides(row, extra), f"run.agent={STUDY_AGENT}", f"env.split={self.tune.split}"]

    def eval_overrides(self, row: StudyRow, threshold: float, min_area: int, extra: list[str] = ()) -> list[str]:
        """Overrides of ``row``'s evaluation at goal threshold ``threshold`` and smallest goal
        component ``min_area`` (map cells)."""
        return [*self.row_overrides(row, extra), f"run.agent={STUDY_AGENT}", f"env.split={self.evaluate.split}",
                f"agent.goal_threshold={threshold!r}", f"agent.goal_min_area_cells={min_area}"]


def load_study(path: str | Path, extra: list[str] = ()) -> tuple[StudyConfig, list[Config]]:
    """The study at ``path`` and, checked, every config it runs: each tuned row's tuning config
    at every grid point and its evaluation config (at the grid's first point: the tuned point
    is not known yet); the preflight gets one tuning config per row, as the grid's points differ
    only in keys that name no file. ``extra``: overrides of every row from the command line. Raises
    ConfigError (one line) for any bad key, value, row or row config. A row the study leaves out
    (``left_out``) runs nothing, so none of its configs is loaded."""
    try:
        study = load_config(path, [], cls=StudyConfig)
    except ConfigError as exc:   # a check of the whole study is named by the file, not the class
        raise ConfigError(f"{path}: {str(exc).removeprefix(f'{StudyConfig.__name__}: ')}") from None
    base = study.config
    configs: list[Config] = []
    for row in study.rows:
        if row.left_out:   # a row that does not run reads nothing
            continue
        try:
            if not row.threshold_from:   # every grid point loads; one per row is preflighted (the tuned
                points = [load_config(base, [*study.tune_overrides(row, extra), f"agent.goal_threshold={t!r}",
                                             f"agent.goal_min_area_cells={a}"])   # keys name no file)
                          for t in study.grid(row) for a in study.tune.min_areas]
                configs.append(points[0])
            source = study.row(row.threshold_from) if row.threshold_from else row
            configs.append(load_config(base, study.eval_overrides(row, study.grid(source)[-1], study.tune.min_areas[0],
                                                                  extra)))
        except ConfigError as exc:
            raise ConfigError(f"{path}: row {row.name}: {exc}") from None
    return study, configs
