"""`calnav study`: the study config's checks (one line, before anything is written), and a tiny
end-to-end study (tune on val, evaluate on test, a transferred threshold, a skipped row) whose
manifest names every row's command, config, inputs and records, and which resumes."""
import json
import textwrap

import pytest

from calnav.common.provenance import git_commit
from calnav.eval.cli import main
from calnav.eval.config import ConfigError, load_config
from calnav.eval.objectnav.study_config import load_study

SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=1", "env.dataset.test_scenes=1",
         "env.dataset.episodes_per_scene=2", "env.max_episode_steps=12", "agent.map_resolution=32x24",
         "agent.map_size_m=16", "mapping.initial_alloc_mb=32", "run.workers=1"]


def _study(tmp_path, rows: str, name: str = "study.yaml", tail: str = ""):
    text = textwrap.dedent(f"""\
        config: objectnav.yaml
        overrides: {json.dumps(SMALL)}
        tune:
          split: val
          episodes: "0:1"
          thresholds: [0.5, 0.9]
          min_areas: [4]
          extend: 0
          metric: success
        evaluate:
          split: test
          episodes: "0:1"
        rows:
        """) + textwrap.indent(textwrap.dedent(rows), "  ") + textwrap.dedent(tail)
    path = tmp_path / name
    path.write_text(text)
    return path


ROWS = """\
- name: gt/ndf
  overrides: [agent.segmenter=gt, agent.map_type=ndf]
- name: gt/rbu
  overrides: [agent.segmenter=gt, mapping.fusion=rbu]
- name: gt/ndf@rbu
  threshold_from: gt/rbu
  overrides: [agent.segmenter=gt, agent.map_type=ndf]
- name: gt/rbu_uncertainty
  threshold_from: gt/rbu
  overrides: [agent.segmenter=gt, mapping.fusion=rbu, agent.uncertainty_aware=true, agent.uncertain_low=0.6]
"""


@pytest.mark.parametrize("rows, message", [
    ("- name: a\n- name: a\n", "row a is listed twice"),
    ("- name: a\n- name: a/b\n", "nest"),
    ("- name: a\n  threshold_from: b\n", "threshold_from 'b' names no earlier row"),
    ("- name: a\n- name: b\n  threshold_from: a\n- name: c\n  threshold_from: b\n", "tunes no threshold of its own"),
    ("- name: a\n  overrides: [agent.goal_threshold=0.5]\n", "agent.goal_threshold is set by the study itself"),
    ("- name: a\n  overrides: [env.split=val]\n", "env.split is set by the study itself"),
    ("- name: ../a\n", "is not a relative path"),
    ("- name: a\n  overrides: [mapping.fusion=nope]\n", "row a: "),
    ("- name: a\n  thresholds: [0.5, 1.5]\n", "outside (0, 1]"),
    ("[]\n", "rows is empty"),
    ("- name: a\n  left_out: ' '\n", "left_out ' ' is blank or padded"),
    ("- name: a\n  left_out: budget\n- name: b\n  threshold_from: a\n", "names a row the study leaves out"),
])
def test_bad_study_is_refused_in_one_line(tmp_path, rows, message):
    with pytest.raises(ConfigError) as exc:
        load_study(_study(tmp_path, rows))
    assert message in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("tail, message", [
    ("questions:\n- ask: a?\n  rows: [a]\n", "a contrast needs 2 or more"),
    ("questions:\n- ask: a?\n  rows: [a, nope]\n", "'nope' names no row"),
    ("questions:\n- ask: a?\n  rows: [a, b]\n  weights: [1, 1]\n", "sum to 0"),
    ("questions:\n- ask: a?\n  rows: [a, b]\n  weights: [1, 0, -1]\n", "3 weights for 2 rows"),
    ("questions:\n- ask: a?\n  rows: [a, b]\n  weights: [.nan, 1]\n", "finite"),
    ("questions:\n- ask: ' '\n  rows: [a, b]\n", "ask is empty"),
    ("questions:\n- ask: a?\n  rows: [a, a]\n", "names a row twice"),
])
def test_bad_question_is_refused_in_one_line(tmp_path, tail, message):
    with pytest.raises(ConfigError) as exc:
        load_study(_study(tmp_path, "- name: a\n- name: b\n", tail=tail))
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_a_question_of_two_rows_is_their_difference(tmp_path):
    study, _ = load_study(_study(tmp_path, "- name: a\n- name: b\n",
                                 tail="questions:\n- ask: a or b?\n  rows: [a, b]\n"))
    assert study.questions[0].weights == [1.0, -1.0]


def test_a_resumed_manifest_keeps_only_rows_of_the_same_inputs(tmp_path):
    """Earlier row entries are kept when the episodes, the base config, the command line's
    result-relevant overrides and the row's overrides and grid are the same; run.workers is
    neutral; another step limit on the command line, or another grid, makes the rows pending."""
    from calnav.eval.objectnav.study import Manifest

    path = _study(tmp_path, "- name: a\n- name: b\n  thresholds: [0.3, 0.6]\n")
    study, _ = load_study(path)

    def carried(extra_then, extra_now, grid_now=None):
        then = Manifest(None, study, path, extra_then).data
        for e in then["rows"].values():
            e["status"] = "done"
        now = Manifest(None, study, path, extra_now)
        if grid_now is not None:
            now.data["rows"]["b"]["thresholds"] = grid_now
        now.carry(then)
        return {n: e["status"] for n, e in now.data["rows"].items()}

    assert carried(["run.workers=2"], ["run.workers=4"]) == {"a": "done", "b": "done"}
    assert carried(["env.max_episode_steps=200"], []) == {"a": "pending", "b": "pending"}
    assert carried([], [], grid_now=[0.3, 0.9]) == {"a": "done", "b": "pending"}
    # a manifest written before rows recorded their grid resumes, and its rows update
    then = Manifest(None, study, path, []).data
    for e in then["rows"].values():
        e.pop("thresholds")
        e["status"] = "tuned"
    now = Manifest(None, study, path, [])
    now.carry(then)
    now.write = lambda: None
    now.update("a", status="done")
    assert now.data["rows"]["a"]["status"] == "done" and now.data["rows"]["a"]["thresholds"] == []


def test_a_left_out_row_runs_nothing_and_says_why(tmp_path, capsys):
    """A row the study file leaves out loads no config (its segmenter need not exist), runs
    nothing, is marked left_out with its reason in the manifest, cannot be asked for with
    --rows, and the report lists it and the question over it as not answered."""
    from calnav.eval.objectnav.study import Manifest
    from calnav.eval.objectnav.study_report import render

    rows = ("- name: a\n  left_out: over the compute budget\n  overrides: [agent.segmenter=nope]\n"
            "- name: b\n  threshold_from: a\n  left_out: over the compute budget\n"
            "- name: c\n  left_out: no scanned houses\n")
    path, out = _study(tmp_path, rows, tail="questions:\n- ask: a or c?\n  rows: [a, c]\n"), tmp_path / "out"
    study, configs = load_study(path)
    assert configs == [] and study.row("a").left_out == "over the compute budget"
    assert main(["study", str(path), "--output", str(out), "--rows", "c"]) == 2
    assert "--rows: c is left out by" in capsys.readouterr().err and not out.exists()
    assert main(["study", str(path), "--output", str(out)]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert {n: (e["status"], e["reason"]) for n, e in manifest["rows"].items()} == {
        "a": ("left_out", "over the compute budget"), "b": ("left_out", "over the compute budget"),
        "c": ("left_out", "no scanned houses")}
    assert not (out / "tune").exists() and not (out / "eval").exists()
    page = render(out / "manifest.json")
    assert "Left out (over the compute budget): a, b. Left out (no scanned houses): c." in page
    assert "| a or c? | a - c | not answered: the study leaves out a, c |" in page
    assert "Not run yet" not in page
    # an earlier invocation's finished entry does not override left_out; a row left out then but
    # not now starts pending (it resumes from its records), not left out with the old reason
    running = load_study(_study(tmp_path, "- name: a\n- name: b\n  threshold_from: a\n- name: c\n", name="then.yaml"))[0]
    then = Manifest(None, running, path, []).data
    then["rows"]["a"]["status"] = "done"
    now = Manifest(None, study, path, [])
    now.carry(then)
    assert now.data["rows"]["a"]["status"] == "left_out"
    back = Manifest(None, running, path, [])
    back.carry(manifest)
    assert {n: e["status"] for n, e in back.data["rows"].items()} == {"a": "pending", "b": "pending", "c": "pending"}


def test_bad_sections_are_refused(tmp_path):
    text = _study(tmp_path, "- name: a\n").read_text().replace("split: test", "split: val")
    (tmp_path / "overlap.yaml").write_text(text)
    with pytest.raises(ConfigError, match="overlap on split val: tune and evaluate on disjoint episodes"):
        load_study(tmp_path / "overlap.yaml")
    (tmp_path / "metric.yaml").write_text(_study(tmp_path, "- name: a\n").read_text().replace("metric: success", "metric: dtg"))
    with pytest.raises(ConfigError, match="valid choices: success, spl, softspl"):
        load_study(tmp_path / "metric.yaml")
    (tmp_path / "nan.yaml").write_text(_study(tmp_path, "- name: a\n").read_text().replace("[0.5, 0.9]", "[.nan]"))
    with pytest.raises(ConfigError, match="tune.thresholds"):
        load_study(tmp_path / "nan.yaml")


def test_study_cli_refuses_before_writing(tmp_path, capsys):
    out = tmp_path / "out"
    path = _study(tmp_path, "- name: a\n  overrides: [agent.segmenter=nope]\n")
    assert main(["study", str(path), "--output", str(out)]) == 2
    assert "row a" in capsys.readouterr().err
    assert main(["study", str(_study(tmp_path, ROWS)), "--output", str(out), "--rows", "gt/x"]) == 2
    assert "no row 'gt/x'" in capsys.readouterr().err
    assert not out.exists()


def test_shipped_study_config_loads():
    study, configs = load_study("configs/study.yaml")
    assert study.evaluate.split == "test" and study.tune.split == "val"
    assert len(study.tune.thresholds) >= 4 and min(len(range(*map(int, study.tune.episodes.split(":")))), 300) == 300
    assert all(c.env.split in ("val", "test") for c in configs)


@pytest.mark.e2e
def test_study_end_to_end(tmp_path, capsys):
    question = "questions:\n- ask: ndf or rbu?\n  rows: [gt/ndf, gt/rbu]\n"
    path, out = _study(tmp_path, ROWS, tail=question), tmp_path / "out"
    assert main(["study", str(path), "--output", str(out), "--rows", "nope"]) == 2   # refused: nothing written
    assert not out.exists()
    assert main(["study", str(path), "--output", str(out)]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    rows = manifest["rows"]
    assert list(rows) == ["gt/ndf", "gt/rbu", "gt/ndf@rbu", "gt/rbu_uncertainty"]
    for name in ("gt/ndf", "gt/rbu"):
        e = rows[name]
        assert e["status"] == "done" and e["tune"]["metric"] == "success"
        assert [g["threshold"] for g in e["tune"]["grid"]] == [0.5, 0.9]
        assert (out / e["tune"]["dir"] / "tune.csv").is_file()
        assert e["command"].startswith("calnav objectnav --config ")
        cfg = load_config(out / e["dir"] / "config.yaml")   # the evaluation at the tuned point, on test
        assert cfg.env.split == "test" and cfg.agent.goal_threshold == e["threshold"]
        assert e["summary"]["count"] == 1 and e["episodes"] == 1 and e["episode_seconds"] > 0
        assert e["episode_files"] and all(len(v) == 64 for v in e["episode_files"].values())
        assert e["config"]["agent"]["goal_threshold"] == e["threshold"]
        assert e["commits"] == {git_commit() or "unrecorded": 1}   # the code that ran its records
        assert e["tune"]["commits"] == {git_commit() or "unrecorded": 2}   # the tuning grid's 2 points x 1 episode
    assert rows["gt/ndf@rbu"]["threshold"] == rows["gt/rbu"]["threshold"]
    if rows["gt/ndf@rbu"]["threshold"] == rows["gt/ndf"]["threshold"]:   # the same config: not run twice
        assert rows["gt/ndf@rbu"]["same_as"] == "gt/ndf"
    else:
        assert rows["gt/ndf@rbu"]["status"] == "done"
    # the uncertainty band [0.6, tuned) is empty at a tuned 0.5, valid at 0.9
    unc = rows["gt/rbu_uncertainty"]
    assert unc["status"] == ("skipped" if rows["gt/rbu"]["threshold"] <= 0.6 else "done")
    assert "row" in capsys.readouterr().out
    assert manifest["questions"] == [{"ask": "ndf or rbu?", "rows": ["gt/ndf", "gt/rbu"], "weights": [1.0, -1.0]}]
    assert main(["report", str(out / "manifest.json")]) == 0
    assert "| ndf or rbu? | gt/ndf - gt/rbu | " in (out / "results.md").read_text()

    # a rerun resumes: nothing runs again, the manifest keeps every row
    before = (out / rows["gt/rbu"]["dir"] / "episodes.jsonl").read_text()
    assert main(["study", str(path), "--output", str(out), "--rows", "gt/rbu"]) == 0
    again = json.loads((out / "manifest.json").read_text())["rows"]
    assert (out / rows["gt/rbu"]["dir"] / "episodes.jsonl").read_text() == before
    assert again["gt/ndf"] == rows["gt/ndf"] and again["gt/rbu"]["summary"] == rows["gt/rbu"]["summary"]

    # more test houses extend the evaluation: only the new episodes run, the first one is kept as it
    # was -- here as if an older commit had run it: the manifest then names both commits
    records = out / rows["gt/rbu"]["dir"] / "episodes.jsonl"
    older = "0" * 40
    records.write_text(before.replace(json.dumps(git_commit()), json.dumps(older)))
    before = records.read_text()
    bigger = path.read_text().replace('"env.dataset.test_scenes=1"', '"env.dataset.test_scenes=2"') \
        .replace('split: test\n  episodes: "0:1"', 'split: test\n  episodes: "0:3"')
    assert bigger.count("test_scenes=2") == 1 and '"0:3"' in bigger
    path.write_text(bigger)
    assert main(["study", str(path), "--output", str(out), "--rows", "gt/rbu"]) == 0
    extended = json.loads((out / "manifest.json").read_text())["rows"]["gt/rbu"]
    text = (out / rows["gt/rbu"]["dir"] / "episodes.jsonl").read_text()
    assert text.startswith(before) and extended["summary"]["count"] == 3 and extended["episodes"] == 3
    assert extended["commits"] == {older: 1, git_commit() or "unrecorded": 2}
    assert main(["report", str(out / "manifest.json")]) == 0
    assert "- `0000000` (1), " in (out / "results.md").read_text()   # the page names both commits


@pytest.mark.e2e
def test_rows_left_out_by_rows_still_count_as_earlier_rows(tmp_path, capsys):
    """``--rows`` that leaves out a finished row whose evaluation config a later row shares: the
    later row names the finished row's records (``same_as``), as in a study run whole, instead
    of running the same episodes again. One-point grids make the shared config certain."""
    rows = """\
- name: gt/ndf
  thresholds: [0.5]
  overrides: [agent.segmenter=gt, agent.map_type=ndf]
- name: gt/rbu
  thresholds: [0.5]
  overrides: [agent.segmenter=gt, mapping.fusion=rbu]
- name: gt/ndf@rbu
  threshold_from: gt/rbu
  overrides: [agent.segmenter=gt, agent.map_type=ndf]
"""
    path, out = _study(tmp_path, rows), tmp_path / "out"
    assert main(["study", str(path), "--output", str(out), "--rows", "gt/ndf"]) == 0
    assert main(["study", str(path), "--output", str(out), "--rows", "gt/ndf@rbu"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())["rows"]
    assert manifest["gt/ndf@rbu"]["same_as"] == "gt/ndf"
    assert manifest["gt/ndf@rbu"]["dir"] == manifest["gt/ndf"]["dir"]
    assert not (out / "eval" / "gt" / "ndf@rbu").exists()

    # records that are not what the manifest it carries says of them: a resume names the row
    records = out / manifest["gt/ndf"]["dir"] / "episodes.jsonl"
    rec = json.loads(records.read_text())
    records.write_text(json.dumps({**rec, "success": 1.0 - rec["success"]}) + "\n")
    assert main(["study", str(path), "--output", str(out), "--rows", "gt/ndf@rbu"]) == 2
    assert f"{out / 'manifest.json'}: row gt/ndf's entry disagrees with its records {records}: " in capsys.readouterr().err


@pytest.mark.e2e
def test_manifest_says_what_is_pending_and_tuned_when_cut_short(tmp_path, monkeypatch):
    """The plan is written before any row runs, and a tuned row is recorded as tuned before its
    evaluation: a study stopped between the two (here: the evaluation fails) says where it is."""
    import calnav.eval.episodes as episodes
    from calnav.eval.objectnav.study import run_study

    real = episodes.episode_indices

    def evaluation_fails(spec, env_cfg, run_cfg, progress=True):
        if env_cfg.split == "test":
            raise RuntimeError("cut short")
        return real(spec, env_cfg, run_cfg, progress)

    monkeypatch.setattr(episodes, "episode_indices", evaluation_fails)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="cut short"):
        run_study(_study(tmp_path, ROWS), out, progress=False)
    rows = json.loads((out / "manifest.json").read_text())["rows"]
    assert rows["gt/ndf"]["status"] == "tuned" and rows["gt/ndf"]["threshold"] in (0.5, 0.9)
    assert [rows[n]["status"] for n in ("gt/rbu", "gt/ndf@rbu", "gt/rbu_uncertainty")] == ["pending"] * 3
