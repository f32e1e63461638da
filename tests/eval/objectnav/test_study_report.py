"""`calnav report`: the study's results page from a hand-made manifest and records, with the
paired differences and verdicts computed by hand; refusals of a missing manifest or records."""
import json

import pytest
from hypothesis import given, settings, strategies as st

from calnav.eval.cli import main
from calnav.eval.config import ConfigError
from calnav.eval.objectnav.study_grids import edge_rows, grids_markdown, transferred_thresholds
from calnav.eval.objectnav.study_ledger import commits_markdown, compute_markdown
from calnav.eval.objectnav.study_report import PAGE_BEGIN, PAGE_END, _ratio, embed, headline, render, transfer_pairs, verdict
from calnav.eval.stats import contrast, failure_kind


def _rec(i, success, spl, steps=20):
    return {"index": i, "episode_id": str(i), "geodesic_distance": 3.0 + i, "category": "chair", "status": "ok",
            "success": float(success), "spl": float(spl), "softspl": float(spl), "distance_to_goal": 0.0 if success else 2.0,
            "steps": steps, "collisions": 1, "wall_time_s": 1.5}


def _study(tmp_path, rows: dict[str, list[dict]], entries: dict[str, dict], pairs, episodes: str = "0:4") -> "Path":
    manifest = {"version": 1, "evaluate": {"split": "test", "episodes": episodes},
                "tune": {"split": "val", "episodes": "0:2", "thresholds": [0.5, 0.9], "metric": "success"},
                "pairs": pairs, "rows": {}}
    for name, e in entries.items():
        if name in rows:
            d = tmp_path / "eval" / name
            d.mkdir(parents=True)
            (d / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows[name]))
            e = {"status": "done", "dir": f"eval/{name}", "episode_seconds": sum(r["wall_time_s"] for r in rows[name]),
                 "config": {"env": {"max_episode_steps": 500}}, **e}
        manifest["rows"][name] = e
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(manifest))
    return path


def _replace_records(path: "Path", row: str, recs: list[dict]) -> None:
    """Row ``row``'s records replaced by ``recs``, its manifest entry's episode seconds with them
    (as `calnav study` rewrites the entry of the records it ran)."""
    (path.parent / "eval" / row / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    from calnav.eval.objectnav.study import manifest_range

    manifest = json.loads(path.read_text())
    wanted = manifest_range(manifest["evaluate"]["episodes"])
    manifest["rows"][row]["episode_seconds"] = sum(r["wall_time_s"] for r in recs if r["index"] in wanted)
    path.write_text(json.dumps(manifest))


def test_verdict_claims_only_beyond_two_sem():
    assert verdict(0.10, 0.05, 600) == "resolved"
    assert verdict(-0.10, 0.05, 600) == "resolved"
    assert verdict(0.099, 0.05, 600) == "not resolved at 600 episodes"
    assert verdict(0.0, 0.0, 10) == "identical on every episode"
    assert verdict(0.1, float("nan"), 1) == "not resolved at 1 episodes"


def test_page_from_hand_made_records(tmp_path):
    base = [_rec(0, 1, 0.5), _rec(1, 0, 0.0, steps=500), _rec(2, 1, 0.8), _rec(3, 0, 0.0)]
    better = [_rec(0, 1, 0.6), _rec(1, 1, 0.4), _rec(2, 1, 0.8), _rec(3, 1, 0.5)]
    entries = {
        "seg/clean/rbu": {"overrides": ["a=1"], "threshold_from": "", "threshold": 0.9,
                          "tune": {"grid": [{"threshold": 0.5, "success": 0.5, "success_sem": 0.1},
                                            {"threshold": 0.9, "success": 0.6, "success_sem": 0.1}],
                                   "threshold": 0.9}},
        "seg/clean/glfs": {"overrides": ["a=2"], "threshold_from": "", "threshold": 0.5},
        "seg/scanned/glfs": {"overrides": ["b=1"], "threshold_from": "", "threshold": 0.5},
        "seg/scanned/glfs@clean": {"overrides": ["b=1"], "threshold_from": "seg/clean/glfs", "threshold": 0.5},
        "seg/later": {"overrides": ["c=1"], "threshold_from": "", "status": "pending"},
        "seg/started": {"overrides": ["f=1"], "threshold_from": "seg/clean/rbu", "status": "pending"},
        "seg/tuned": {"overrides": ["e=1"], "threshold_from": "", "status": "tuned", "threshold": 0.7},
        "seg/low": {"overrides": ["d=1"], "threshold_from": "seg/clean/rbu", "status": "skipped", "reason": "band empty"},
    }
    rows = {"seg/clean/rbu": base, "seg/clean/glfs": better, "seg/scanned/glfs": better, "seg/scanned/glfs@clean": base}
    path = _study(tmp_path, rows, entries, [["seg/clean/glfs", "seg/clean/rbu"]])
    (tmp_path / "eval" / "seg" / "tuned").mkdir(parents=True)   # its evaluation half done: 2 of 4 episodes
    (tmp_path / "eval" / "seg" / "tuned" / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in base[:2]))
    (tmp_path / "eval" / "seg" / "started").mkdir(parents=True)   # a transfer row whose evaluation has begun: 1 of 4
    (tmp_path / "eval" / "seg" / "started" / "episodes.jsonl").write_text(json.dumps(base[0]) + "\n")
    page = render(path)
    # metrics: rbu Success 2/4 = 0.5, SEM = std([1,0,1,0], ddof=1) / 2 = 0.2887
    assert "| seg/clean/rbu | 0.9 | 0.500 (0.289) |" in page
    assert "| seg/scanned/glfs@clean | 0.5 (seg/clean/glfs) | 0.500 (0.289) |" in page
    # glfs - rbu, Success: diffs [0, 1, 0, 1]: mean 0.5, SEM 0.2887 -> 1.7 SEM, not resolved; SPL: diffs
    # [0.1, 0.4, 0, 0.5]: mean 0.25, SD sqrt(0.17 / 3) = 0.238, SEM 0.119
    assert "| seg/clean/glfs | seg/clean/rbu | +0.500 (0.289, -) | +0.250 (0.119, -) | 1.73 | not resolved at 4 episodes | 4 |" in page
    # transfer: the clean-tuned threshold on scanned houses minus the scanned-tuned one: -0.5
    assert transfer_pairs(json.loads(path.read_text())) == [("seg/scanned/glfs@clean", "seg/scanned/glfs")]
    assert "| seg/scanned/glfs@clean | seg/scanned/glfs | -0.500 (0.289, -) |" in page
    assert "None yet" not in page
    assert "Evaluation not finished: seg/started (1 of 4 episodes evaluated)." in page
    assert "Not run yet: seg/later." in page and "Tuned, evaluation not finished: seg/tuned (threshold 0.7; 2 of 4 episodes evaluated)." in page and "Skipped: seg/low (band empty)." in page
    # failures: rbu has one false STOP (2 m from the goal) and one episode out of steps (500 of
    # 500) that walked nowhere: stuck
    assert "| seg/clean/rbu | 2 | 1 | 0 | 0 | 1 | 0 | 1 | 4 |" in page
    assert "evaluation compute 0.01 worker-hours" in page
    # the tuning grid of the one row that tuned, the chosen point in bold, and the figure beside it
    assert "| seg/clean/rbu | 0.5: 0.500 (0.100), **0.9: 0.600 (0.100)** | 0.9 | - |" in page
    assert "![Success against the goal threshold, per tuned row](threshold_curves.png)" in page

    out = tmp_path / "report"
    assert main(["report", str(path), "--output", str(out)]) == 0
    assert (out / "results.md").read_text() == page
    assert (out / "threshold_curves.png").stat().st_size > 0


def test_a_study_with_one_row_says_no_pair_is_ready(tmp_path):
    entries = {"a": {"overrides": ["x=1"], "threshold_from": "", "threshold": 0.5},
               "b": {"overrides": ["x=2"], "threshold_from": "", "status": "pending"}}
    page = render(_study(tmp_path, {"a": [_rec(0, 1, 0.5), _rec(1, 0, 0.0)]}, entries, [["b", "a"]]))
    assert "None yet: no pair has both rows evaluated." in page and "Not run yet: b." in page


def test_missing_manifest_or_records_is_one_line(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nope.json")]) == 2
    assert "manifest" in capsys.readouterr().err
    path = _study(tmp_path, {}, {"r": {"overrides": [], "threshold_from": "", "status": "done", "dir": "eval/r",
                                       "threshold": 0.5}}, [])
    with pytest.raises(ConfigError, match="row r: records .* not found"):
        render(path)


def test_failure_kinds():
    ok = {"status": "ok", "success": 0.0, "spl": 0.0, "softspl": 0.1, "steps": 40, "path_length": 5.0}
    assert failure_kind({**ok, "success": 1.0, "distance_to_goal": 0.0}, 500, 0.25) is None
    assert failure_kind({**ok, "distance_to_goal": 1.0}, 500, 0.25) == "stopped_short"     # at the 1 m edge
    assert failure_kind({**ok, "distance_to_goal": 1.01}, 500, 0.25) == "false_stop"
    # 500 steps could walk 125 m: 31.25 m is exactly a quarter (searching), below it stuck
    assert failure_kind({**ok, "distance_to_goal": 4.0, "steps": 500, "path_length": 31.25}, 500, 0.25) == "searching"
    assert failure_kind({**ok, "distance_to_goal": 4.0, "steps": 500, "path_length": 31.0}, 500, 0.25) == "stuck"
    assert failure_kind({"status": "error", "error": "boom"}, 500, 0.25) == "crashed"
    assert failure_kind({**ok, "distance_to_goal": float("nan")}, 500, 0.25) == "crashed"   # a non-finite metric


def test_contrast_by_hand():
    """A difference of differences, episode by episode: (a - b) - (c - d) on the 3 episodes all
    four runs hold (episode 3 is missing from d): [1-0-(0-0), 1-1-(1-0), 0-0-(0-1)] = [1, -1, 1],
    mean 1/3, SD sqrt(((2/3)^2 + (4/3)^2 + (2/3)^2) / 2) = 1.1547, SEM 0.6667."""
    run = lambda *s: [_rec(i, v, v / 2) for i, v in enumerate(s)]
    a, b, c, d = run(1, 1, 0, 1), run(0, 1, 0, 1), run(0, 1, 0, 0), run(0, 0, 1)
    m, sem, n = contrast([(a, 1), (b, -1), (c, -1), (d, 1)], "success")
    assert n == 3 and m == pytest.approx(1 / 3) and sem == pytest.approx(2 / 3)
    m, sem, n = contrast([(a, 1), (b, -1), (c, -1), (d, 1)], "spl")   # every SPL is half the Success
    assert m == pytest.approx(1 / 6) and sem == pytest.approx(1 / 3)


def _questions(tmp_path, questions):
    base = [_rec(0, 1, 0.5), _rec(1, 0, 0.0), _rec(2, 1, 0.8), _rec(3, 0, 0.0)]
    better = [_rec(0, 1, 0.6), _rec(1, 1, 0.4), _rec(2, 1, 0.8), _rec(3, 1, 0.5)]
    entries = {"r": {"overrides": ["a=1"], "threshold_from": "", "threshold": 0.9},
               "g": {"overrides": ["a=2"], "threshold_from": "", "threshold": 0.5},
               "p": {"overrides": ["a=3"], "threshold_from": "", "status": "pending"}}
    path = _study(tmp_path, {"r": base, "g": better}, entries, [])
    manifest = json.loads(path.read_text())
    manifest["questions"] = questions
    path.write_text(json.dumps(manifest))
    return path


def test_conclusions_answer_each_question_or_say_what_it_waits_for(tmp_path):
    page = render(_questions(tmp_path, [{"ask": "g better?", "rows": ["g", "r"], "weights": [1.0, -1.0]},
                                        {"ask": "p better?", "rows": ["p", "r"], "weights": [1.0, -1.0]}]))
    # g - r as in test_page_from_hand_made_records: Success +0.5 (0.289), 1.7 SEM; the records
    # name no house, so there is no house SEM ("-") and the episode SEM judges
    assert "| g better? | g - r | +0.500 (0.289, -) | +0.250 (0.119, -) | 1.73 | not resolved at 4 episodes | 4 |" in page
    assert "| p better? | p - r | waiting for p |" in page
    page = render(_questions(tmp_path / "none", []))
    assert "The study file asks no questions." in page
    assert "fewer records" not in page
    _replace_records(tmp_path / "none" / "manifest.json", "g", [_rec(0, 1, 0.5)])
    assert "Rows holding fewer records than the evaluation episodes (rerun `calnav study` to fill them): g (1 of 4)." \
        in render(tmp_path / "none" / "manifest.json")


def test_the_house_sem_judges_when_a_house_s_episodes_agree(tmp_path):
    """Success differences [1, 1, 1, 1, 0, 0], the four 1s in house A, the 0s in house B: mean
    2/3, episode SEM sqrt((4/9 * 4 + 4/9 * 2 ... ) -> SD sqrt(12/45) = 0.5164, SEM 0.2108 (3.16 SEM,
    resolved on episodes); house residual sums S_g - n_g m = 4 - 8/3 = 4/3 and 0 - 4/3, CR1 SEM
    sqrt(2/1 * 32/9) / 6 = 0.4444: 1.5 SEM (printed rounded down: 1.49), not resolved. SPL is half
    of Success throughout."""
    houses = "AAAABB"
    rec = lambda i, v: {**_rec(i, v, v / 2), "scene": houses[i]}
    entries = {"r": {"overrides": ["a=1"], "threshold_from": "", "threshold": 0.9},
               "g": {"overrides": ["a=2"], "threshold_from": "", "threshold": 0.5}}
    path = _study(tmp_path, {"r": [rec(i, 0) for i in range(6)], "g": [rec(i, 1 if i < 4 else 0) for i in range(6)]},
                  entries, [["g", "r"]], episodes="0:6")
    page = render(path)
    assert "| g | r | +0.667 (0.211, 0.444) | +0.333 (0.105, 0.222) | 1.49 | not resolved at 6 episodes | 6 |" in page
    assert "judged by the larger of the episode SEM and the house SEM" in page


def test_clustered_sem_by_hand():
    """[1, 1, 0, 0] in houses A, A, B, B: residual sums +1, -1, CR1 SEM sqrt(2 * 2) / 4 = 0.5
    against the episode SEM 0.2887; with one value per house it is the episode SEM."""
    import numpy as np

    from calnav.eval.stats import clustered_sem, mean_sem

    assert clustered_sem([1, 1, 0, 0], "AABB") == pytest.approx(0.5)
    x = np.random.default_rng(0).normal(size=17)
    assert clustered_sem(x, range(17)) == pytest.approx(mean_sem(x)[1])
    assert np.isnan(clustered_sem([1, 0, 1], "AAA"))   # one house: no spread between houses
    with pytest.raises(ValueError, match="3 values but 2 group labels"):
        clustered_sem([1, 0, 1], "AB")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-1, 1), st.integers(0, 5)), min_size=3, max_size=40), st.floats(0.1, 10))
def test_clustered_sem_properties(pairs, scale):
    """Renaming the houses or reordering the episodes leaves it unchanged; scaling every
    difference scales it; shifting every difference leaves it unchanged (a spread, not a level)."""
    import numpy as np

    from calnav.eval.stats import clustered_sem

    x = np.array([v for v, _ in pairs])
    g = [f"h{h}" for _, h in pairs]
    base = clustered_sem(x, g)
    if np.isnan(base):
        assert len(set(g)) < 2
        return
    order = np.random.default_rng(len(pairs)).permutation(len(pairs))
    assert clustered_sem(x[order], [g[i] + "_renamed" for i in order]) == pytest.approx(base, abs=1e-12)
    assert clustered_sem(scale * x, g) == pytest.approx(scale * base, rel=1e-9, abs=1e-12)
    assert clustered_sem(x + 0.5, g) == pytest.approx(base, rel=1e-9, abs=1e-12)


def test_the_sem_ratio_rounds_down():
    """1.996 SEM is not resolved, so it must not print as 2.00."""
    assert _ratio(0.1996, 0.1) == "1.99" and _ratio(-0.2, 0.1) == "2.00" and _ratio(0.1, 0.0) == "-"


def test_rows_on_other_episodes_are_not_paired(tmp_path):
    """Another house style reuses the indices for other episodes: a question or pair across them
    is refused in one line, as is one whose rows share no episode."""
    other = [{**_rec(i, 1, 0.5), "geodesic_distance": 9.0 + i} for i in range(4)]
    path = _questions(tmp_path, [{"ask": "across styles?", "rows": ["g", "r"], "weights": [1.0, -1.0]}])
    _replace_records(path, "g", other)
    with pytest.raises(ConfigError, match=r"^rows g and r hold different episodes at index 0 \(0 vs 0\); a paired"):
        render(path)
    _replace_records(path, "g", [_rec(7, 1, 0.5)])
    with pytest.raises(ConfigError, match="^rows g and r share no evaluation episode"):
        render(path)


def test_compute_counts_records_and_the_plan_left(tmp_path):
    """2 rows evaluated (4 episodes each, 1.5 s), one tuning dir of 2 episodes, a pending row:
    its grid (2 thresholds x 2 tuning episodes) and its 4 evaluation episodes are left."""
    path = _questions(tmp_path, [])
    tune = tmp_path / "tune" / "r" / "0.5_4"
    tune.mkdir(parents=True)
    (tune / "episodes.jsonl").write_text("".join(json.dumps(_rec(i, 1, 0.5)) + "\n" for i in range(2)))
    text = compute_markdown(tmp_path, json.loads(path.read_text()))
    assert text.startswith("Compute so far: 2 tuning episodes (0.0 worker-hours) and 8 evaluation episodes (0.0 "
                           "worker-hours), 1.50 s per episode on one core;")
    assert "The plan still needs about 8 episodes" in text and "leaves out" not in text
    # a row left out after 1 of its tuning episodes: 2 x 2 - 1 tuning + 4 evaluation episodes, at
    # 1.5 s each, are what the cut saves; they are not in the plan left
    manifest = json.loads(path.read_text())
    manifest["rows"]["x"] = {"overrides": ["a=4"], "threshold_from": "", "status": "left_out", "reason": "budget"}
    (tmp_path / "tune" / "x" / "0.5_4").mkdir(parents=True)
    (tmp_path / "tune" / "x" / "0.5_4" / "episodes.jsonl").write_text(json.dumps(_rec(0, 1, 0.5)) + "\n")
    text = compute_markdown(tmp_path, manifest)
    assert text.startswith("Compute so far: 3 tuning episodes")
    assert "The plan still needs about 8 episodes" in text
    assert text.endswith("The rows the study leaves out would need about 7 more (0.0 worker-hours, about 0.0 hours "
                         "on 2 cores).")
    manifest["rows"]["p"] = {**manifest["rows"]["p"], "status": "left_out", "reason": "budget", "thresholds": [0.3]}
    (tmp_path / "eval" / "p").mkdir(parents=True)   # it had evaluated 1 episode: it counts as run
    (tmp_path / "eval" / "p" / "episodes.jsonl").write_text(json.dumps(_rec(0, 1, 0.5)) + "\n")
    text = compute_markdown(tmp_path, manifest)   # nothing left to run: p's own 1-point grid x 2 + 3 join the cut
    assert text.startswith("Compute so far: 3 tuning episodes (0.0 worker-hours) and 9 evaluation episodes")
    assert "Every row the study runs has run. The rows the study leaves out would need about 12 more" in text


def test_report_embeds_the_headline_in_pages_and_refuses_a_page_without_its_block(tmp_path, capsys):
    path = _questions(tmp_path, [{"ask": "g better?", "rows": ["g", "r"], "weights": [1.0, -1.0]}])
    page = tmp_path / "README.md"
    page.write_text(f"# title\n\n{PAGE_BEGIN}\nstale text\n{PAGE_END}\n\nafter\n")
    bad = tmp_path / "other.md"
    bad.write_text("no block\n")
    assert main(["report", str(path), "--page", str(page), "--page", str(bad)]) == 2
    assert "--page" in capsys.readouterr().err and not (tmp_path / "results.md").exists()   # nothing written
    assert "stale text" in page.read_text()
    assert main(["report", str(path), "--page", str(page)]) == 0
    text = page.read_text()
    assert text.startswith("# title\n\n" + PAGE_BEGIN + "\n") and text.endswith(PAGE_END + "\n\nafter\n")
    assert "stale text" not in text and "| g better? | g - r |" in text and "[the results page](results.md)" in text
    assert embed(text, "x", page) == f"# title\n\n{PAGE_BEGIN}\nx\n{PAGE_END}\n\nafter\n"
    manifest = json.loads(path.read_text())   # the headline says what the study leaves out, and why
    manifest["rows"]["p"] = {**manifest["rows"]["p"], "status": "left_out", "reason": "over budget."}
    path.write_text(json.dumps(manifest))
    text = headline(path, page, tmp_path / "results.md")
    assert "2 of 3 rows evaluated on" in text and "mean (SEM); the study leaves out 1 (below). Everything" in text
    assert "\n\nLeft out (over budget): p.\n\n| Row |" in text
    (tmp_path / "eval" / "p").mkdir()   # its evaluation had begun: 1 of 4 episodes
    (tmp_path / "eval" / "p" / "episodes.jsonl").write_text(json.dumps(_rec(0, 1, 0.5)) + "\n")
    assert "Left out (over budget): p (1 of 4 episodes evaluated)." in headline(path, page, tmp_path / "results.md")


def test_committed_results_page_is_what_report_renders():
    """docs/objectnav_study/study/results.md is `calnav report`'s rendering of the committed
    manifest and records, byte for byte: no number on the page is typed by hand."""
    from pathlib import Path

    study = Path(__file__).resolve().parents[3] / "docs" / "objectnav_study" / "study"
    assert (study / "manifest.json").is_file() and (study / "results.md").is_file()
    assert (study / "results.md").read_text(encoding="utf-8") == render(study / "manifest.json")


def test_readme_and_study_page_headlines_are_what_report_renders():
    """README.md's and docs/objectnav_study.md's study blocks are `calnav report --page`'s
    rendering of the committed manifest and records."""
    from pathlib import Path

    repo = Path(__file__).resolve().parents[3]
    manifest = repo / "docs" / "objectnav_study" / "study" / "manifest.json"
    for page in (repo / "README.md", repo / "docs" / "objectnav_study.md"):
        text = page.read_text(encoding="utf-8")
        block = headline(manifest.relative_to(repo), page, manifest.parent / "results.md")
        assert embed(text, block, page) == text, f"{page.name}: rerun calnav report --page"


def test_commits_line_groups_rows_by_the_commits_that_ran_them():
    a, b = "a" * 40, "b" * 40
    records = {"r/one": [{"commit": a}, {"commit": a}, {"commit": b}],
               "r/two": [{"commit": b}, {"commit": a}, {"commit": a}],   # the same counts: one line
               "r/old": [{}, {"commit": None}, {"commit": b}]}           # made before records named their commit
    assert commits_markdown(records).splitlines()[2:] == [
        "- `aaaaaaa` (2), `bbbbbbb` (1): r/one, r/two",
        "- `bbbbbbb` (1), unrecorded (2): r/old"]


def test_rows_tuned_on_an_edge_of_their_grid():
    def row(threshold, successes, **extra):
        grid = [{"threshold": t, "min_area": 4, "success": v} for t, v in successes.items()]
        return {"threshold_from": "", "threshold": threshold, "tune": {"grid": grid, "threshold": threshold}, **extra}

    manifest = {"tune": {"metric": "success"}, "rows": {
        "top": row(0.975, {0.9: 0.60, 0.95: 0.61, 0.975: 0.63}),     # still rising at the top: listed
        "inside": row(0.7, {0.5: 0.5, 0.7: 0.6, 0.9: 0.55}),        # bracketed
        "flat": row(0.7, {0.7: 0.6, 0.9: 0.6}),                     # ties its neighbour (the lower wins): not
        "bottom": row(0.3, {0.3: 0.7, 0.5: 0.6}),                   # best at the bottom, 0.1 still possible
        "at_one": row(1.0, {0.9: 0.5, 1.0: 0.6}),                   # nowhere to go above 1
        "taken": {"threshold_from": "top", "threshold": 0.975},     # takes another row's threshold: no grid
    }}
    assert edge_rows(manifest) == [("top", 0.975), ("bottom", 0.3)]


def test_grid_table_names_the_thresholds_transferred_to_a_condition():
    def tuned(threshold, grid):
        return {"threshold_from": "", "overrides": [], "threshold": threshold, "tune": {
            "threshold": threshold, "min_area": 4,
            "grid": [{"threshold": x, "min_area": a, "success": s, "success_sem": 0.02} for x, a, s in grid]}}

    manifest = {"tune": {"split": "val", "episodes": "0:300"}, "rows": {
        "rgb/clean/rbu": {**tuned(0.9, [(0.5, 4, 0.8), (0.9, 4, 0.85)]), "overrides": ["clean"]},
        # its own grid at the chosen min_area only: the min_area 8 point is not this curve's
        "rgb/scanned/rbu": {**tuned(0.5, [(0.5, 4, 0.6), (0.9, 4, 0.55), (0.9, 8, 0.9)]), "overrides": ["scanned"]},
        "rgb/scanned/rbu@clean": {"threshold_from": "rgb/clean/rbu", "overrides": ["scanned"], "status": "pending"},
        "rgb/scanned/rbu_stop": {"threshold_from": "rgb/clean/rbu", "overrides": ["scanned", "stop"]},  # another condition
        "rgbd/clean/rbu@rgb": {"threshold_from": "rgb/clean/rbu", "overrides": ["rgbd"]},   # rgbd not tuned yet
    }}
    # the pending transfer row already names its threshold: the source row's tuned one
    assert transferred_thresholds(manifest) == {"rgb/scanned/rbu": [(0.9, "rgb/clean/rbu")]}
    assert grids_markdown(manifest).splitlines()[2:] == [
        "| rgb/clean/rbu | 0.5: 0.800 (0.020), **0.9: 0.850 (0.020)** | 0.9 | - |",
        "| rgb/scanned/rbu | **0.5: 0.600 (0.020)**, 0.9: 0.550 (0.020) | 0.5 | 0.9 (rgb/clean/rbu) |"]
    assert grids_markdown({"tune": {}, "rows": {"a": {"threshold_from": "b"}}}) == ""
    # a transfer whose row or own tuned row the study leaves out is no transfer pair
    for left_out in ("rgb/scanned/rbu@clean", "rgb/scanned/rbu"):
        rows = {**manifest["rows"], left_out: {**manifest["rows"][left_out], "status": "left_out"}}
        assert transfer_pairs({**manifest, "rows": rows}) == []


def _claimed(recs: list[dict]) -> dict:
    """What `calnav study` writes of a row's records in its manifest entry."""
    from calnav.eval.objectnav.study import record_commits
    from calnav.eval.stats import summarize

    return {"episodes": len(recs), "episode_seconds": round(sum(r["wall_time_s"] for r in recs), 3),
            "commits": record_commits(recs), "summary": {k: v for k, v in summarize(recs).items() if k != "per_category"}}


def test_two_different_records_of_one_episode_in_a_row_are_refused(tmp_path):
    """A row holding a success and a failure of episode 2: the page would show either one."""
    from calnav.eval.results_dir import ResultsError

    base = [_rec(0, 1, 0.5), _rec(1, 0, 0.0), _rec(2, 1, 0.8), _rec(3, 0, 0.0)]
    path = _study(tmp_path, {"r": base}, {"r": {"overrides": [], "threshold_from": "", "threshold": 0.5}}, [])
    with (tmp_path / "eval" / "r" / "episodes.jsonl").open("a") as f:
        f.write(json.dumps(_rec(2, 0, 0.0)) + "\n")
    with pytest.raises(ResultsError, match=rf"^{tmp_path / 'eval' / 'r'}: episode 2 has two different records "
                                           r"\(episodes.jsonl lines 3 and 5: distance_to_goal 0.0 vs 2.0, softspl"):
        render(path)
    assert main(["report", str(path)]) == 2 and not (tmp_path / "results.md").exists()


def test_a_manifest_that_disagrees_with_its_records_is_named(tmp_path):
    """The manifest's episode count, summary and tuning grid are checked against the records they
    come from: a row entry written from other records is one line naming the row and the field."""
    from calnav.eval.results_dir import ResultsError

    base = [_rec(0, 1, 0.5), _rec(1, 0, 0.0), _rec(2, 1, 0.8), _rec(3, 0, 0.0)]
    entry = {"overrides": [], "threshold_from": "", "threshold": 0.5, **_claimed(base)}
    path = _study(tmp_path, {"r": base}, {"r": entry}, [])
    good = json.loads(path.read_text())
    assert "| r | 0.5 | 0.500 (0.289) |" in render(path)   # the entry as `calnav study` writes it

    def refused(change, match: str) -> None:
        manifest = json.loads(json.dumps(good))
        change(manifest["rows"]["r"])
        path.write_text(json.dumps(manifest))
        with pytest.raises(ResultsError, match=match):
            render(path)

    records = tmp_path / "eval" / "r" / "episodes.jsonl"
    refused(lambda e: e["summary"].update(success=0.75),
            rf"^{path}: row r's entry disagrees with its records {records}: success 0.75 where the records give 0.5; "
            r"the records are the results: rerun `calnav study` on the row \(--rows r\) to rewrite its entry")
    refused(lambda e: e.update(episodes=1200), r"row r's entry .*: episodes 1200 where the records give 4; ")
    refused(lambda e: e.update(episodes=5, episode_seconds=7.5), r": episodes 5 where the records give 4 \(and 1 more field\(s\)\)")
    # a tuning grid point's figures against that point's records
    point = tmp_path / "tune" / "r" / "0.5_4"
    point.mkdir(parents=True)
    (point / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in base[:2]))
    grid = [{"threshold": 0.5, "min_area": 4, "success": 0.5, "success_sem": 0.5, "spl": 0.25, "spl_sem": 0.25,
             "softspl": 0.25, "dtg": 1.0, "n": 2}]
    good["rows"]["r"]["tune"] = {"dir": "tune/r", "grid": grid, "threshold": 0.5}
    path.write_text(json.dumps(good))
    render(path)
    refused(lambda e: e["tune"]["grid"][0].update(n=300), rf"row r's tuning grid point 0.5_4 disagrees with its "
                                                          rf"records {point / 'episodes.jsonl'}: n 300 where the records give 2;")


def test_a_half_finished_row_is_never_called_run(tmp_path):
    """A finished row holding 2 of its 4 evaluation episodes (its manifest entry agrees): the page
    names it as short, and the compute line counts its 2 missing episodes as left to run."""
    path = _questions(tmp_path, [])
    manifest = json.loads(path.read_text())
    del manifest["rows"]["p"]   # no pending row: only the short one is unfinished
    path.write_text(json.dumps(manifest))
    _replace_records(path, "g", [_rec(0, 1, 0.5), _rec(1, 1, 0.5)])
    page = render(path)
    assert "Rows holding fewer records than the evaluation episodes (rerun `calnav study` to fill them): g (2 of 4)." in page
    assert "Every row the study runs has run." not in page
    assert "The plan still needs about 2 episodes" in page
    _replace_records(path, "g", [_rec(i, 1, 0.5) for i in range(4)])
    assert "Every row the study runs has run." in render(path)


def test_jackknife_sem_by_hand():
    """Leave-one-out values [1, 2, 4]: mean 7/3, squared deviations 16/9 + 1/9 + 25/9 = 42/9,
    SE = sqrt(2/3 * 42/9) = sqrt(28/9) = 1.7638; for a mean it is the ordinary SEM."""
    import numpy as np

    from calnav.eval.stats import jackknife_sem, mean_sem

    assert jackknife_sem([1, 2, 4]) == pytest.approx(np.sqrt(28 / 9))
    x = np.random.default_rng(1).normal(size=9)
    loo = [(x.sum() - v) / (len(x) - 1) for v in x]
    assert jackknife_sem(loo) == pytest.approx(mean_sem(x)[1])
    assert np.isnan(jackknife_sem([0.5]))
