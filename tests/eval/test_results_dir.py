"""eval.results_dir through the commands that use it: the lock (a second run into one --output is
refused, a killed run does not leave it stuck), duplicate / damaged / crashed records on resume,
results directories that cannot be used, and runs whose episodes all crash."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from calnav.eval.cli import main
from calnav.eval.results_dir import RECORDS_NAME as RECORDS, ResultsDir, ResultsError, read_records

SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]
REPO_ROOT = Path(__file__).resolve().parents[2]
LOCK_HOLDER = ("import sys, time; from calnav.eval.results_dir import ResultsDir; ResultsDir(sys.argv[1]).open(); "
               "print('locked', flush=True); time.sleep(600)")

pytestmark = pytest.mark.e2e


def _objectnav(out: Path, episodes: str = "0:4", *extra: str) -> list[str]:
    return ["objectnav", "--agent", "oracle", "--episodes", episodes, "--output", str(out), "run.workers=1",
            *SMALL, *extra]


def _lines(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """An oracle run of episodes 0:4, finished once for the module (copy it before changing it)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    assert main(_objectnav(out)) == 0
    return out


@pytest.fixture
def run_copy(finished_run, tmp_path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(finished_run, out)
    return out


def test_second_run_is_refused_while_the_first_holds_the_directory_and_not_after_kill9(tmp_path, capsys):
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    holder = subprocess.Popen([sys.executable, "-c", LOCK_HOLDER, str(out)], cwd=REPO_ROOT, env=env,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert main(_objectnav(out, "0:2")) == 2
        err = _one_line_error(capsys, "objectnav")
        assert f"{out} is in use by another calnav run (pid {holder.pid})" in err
        assert not (out / "episodes.jsonl").exists()  # the refused run wrote nothing
        with pytest.raises(ResultsError, match="in use"):
            ResultsDir(out).open()
    finally:
        holder.send_signal(signal.SIGKILL)  # kill -9: no clean-up code runs in the holder
        holder.wait()
    assert main(_objectnav(out, "0:2")) == 0  # the kernel released the lock with the process
    assert sorted(r["index"] for r in _lines(out)) == [0, 1]


def test_lock_is_released_when_the_run_ends(tmp_path):
    with ResultsDir(tmp_path / "d"):
        pass
    with ResultsDir(tmp_path / "d"):  # not stuck after a clean exit either
        pass


def test_duplicate_record_counts_once_and_is_reported(run_copy, capsys):
    records = run_copy / "episodes.jsonl"
    lines = records.read_text().splitlines()
    records.write_text("\n".join(lines + [lines[2]]) + "\n")  # episode 2 twice: N was 5 for 0:4
    assert main(_objectnav(run_copy)) == 0
    summary = json.loads((run_copy / "summary.json").read_text())
    assert summary["count"] == 4 and summary["duplicates"] == 1
    assert "1 duplicate record(s) of episode(s) 2" in capsys.readouterr().err
    assert sorted(r["index"] for r in _lines(run_copy)) == [0, 1, 2, 3]  # the file holds each once


def test_summary_reports_zero_duplicates_normally(finished_run):
    assert json.loads((finished_run / "summary.json").read_text())["duplicates"] == 0


def test_non_object_json_line_is_skipped_and_its_episode_rerun(run_copy, capsys):
    records = run_copy / "episodes.jsonl"
    lines = records.read_text().splitlines()
    lost = json.loads(lines[1])["index"]
    records.write_text("\n".join([lines[0], "5", *lines[2:]]) + "\n")
    assert main(_objectnav(run_copy)) == 0
    err = capsys.readouterr().err
    assert f"{records}:2: skipped a damaged record (a JSON int, not an object)" in err
    got = _lines(run_copy)
    assert sorted(r["index"] for r in got) == [0, 1, 2, 3] and got[-1]["index"] == lost  # re-run


def test_record_without_its_metrics_is_damaged_and_rerun(run_copy, capsys):
    """A record {"index": 3} is damaged and rerun, not counted as a finished episode (N=4, SPL over 3)."""
    records = run_copy / "episodes.jsonl"
    lines = records.read_text().splitlines()
    lost = json.loads(lines[3])["index"]
    records.write_text("\n".join([*lines[:3], json.dumps({"index": lost})]) + "\n")
    assert main(_objectnav(run_copy)) == 0
    assert f"episode {lost} has no number for success, spl, softspl, distance_to_goal; it runs again" in \
        capsys.readouterr().err
    got = _lines(run_copy)
    assert sorted(r["index"] for r in got) == [0, 1, 2, 3] and all("spl" in r for r in got)
    summary = json.loads((run_copy / "summary.json").read_text())
    assert summary["count"] == 4 and summary["success"] == 1.0


def test_read_records_skips_damage_and_counts_an_exact_duplicate_once(tmp_path, capsys):
    p = tmp_path / "episodes.jsonl"
    m = '"success": 1, "spl": 0.5, "softspl": 0.5, "distance_to_goal": 0.0'
    # the duplicate ran elsewhere (another wall time and commit): the same result, counted once
    p.write_text(f'{{"index": 0, "v": 1, "wall_time_s": 2.0, {m}}}\n[1, 2]\n{{"v": 3}}\n'
                 f'{{"index": 0, "v": 1, "wall_time_s": 3.5, "commit": "abc", {m}}}\n{{"index": 1, "v"')
    read = read_records(p)
    assert read.records[0]["wall_time_s"] == 3.5 and list(read.records) == [0] and read.duplicates == 1
    assert read.damaged == [2, 3, 5] and not read.clean_end
    err = capsys.readouterr().err
    assert f"{p}:3: skipped a damaged record (no integer 'index')" in err and f"{p}:5:" in err
    assert "1 duplicate record(s) of episode(s) 0; each episode counts once (the records are the same result)" in err


def test_two_different_records_of_one_episode_are_refused_by_every_reader(tmp_path):
    """One success and one failure of episode 3: no reader may pick one (the report, compare and
    a resume all read records through read_records)."""
    p = tmp_path / "run" / "episodes.jsonl"
    p.parent.mkdir()
    m = '"spl": 0.5, "softspl": 0.5, "distance_to_goal": 0.0'
    p.write_text(f'{{"index": 3, "success": 1, {m}}}\n{{"index": 4, "success": 1, {m}}}\n'
                 f'{{"index": 3, "success": 0, {m}, "wall_time_s": 1.0}}\n')
    with pytest.raises(ResultsError, match=rf"^{tmp_path / 'run'}: episode 3 has two different records \(episodes.jsonl "
                                           r"lines 1 and 3: success 1 vs 0\); one episode has one result: delete the "
                                           r"wrong line \(or both, and rerun the same command to run the episode again\)$"):
        read_records(p, quiet=True)


def test_a_resume_refuses_two_different_records_of_one_episode(run_copy, capsys):
    records = run_copy / "episodes.jsonl"
    lines = records.read_text().splitlines()
    other = {**json.loads(lines[2]), "success": 1.0 - json.loads(lines[2])["success"]}
    records.write_text("\n".join(lines + [json.dumps(other)]) + "\n")
    before = records.read_text()
    assert main(_objectnav(run_copy)) == 2
    err = capsys.readouterr().err
    assert f"{run_copy}: episode {other['index']} has two different records (episodes.jsonl lines 3 and 5: success" in err
    assert records.read_text() == before   # nothing rewritten: the records stay as they were


def test_crashed_episode_is_retried_and_replaced(run_copy):
    records = run_copy / "episodes.jsonl"
    lines = records.read_text().splitlines()
    crashed = json.loads(lines[1])["index"]
    lines[1] = json.dumps({"index": crashed, "status": "error", "error": "RuntimeError: boom"})
    records.write_text("\n".join(lines) + "\n")
    assert main(_objectnav(run_copy)) == 0
    got = _lines(run_copy)
    assert sorted(r["index"] for r in got) == [0, 1, 2, 3]  # never two records of one index
    assert all(r["status"] == "ok" for r in got)
    summary = json.loads((run_copy / "summary.json").read_text())
    assert summary["failed"] == 0 and summary["success"] == 1.0


def _one_line_error(capsys, command: str) -> str:
    """The error line, checked to be the one last line of stderr (progress bars may precede it)
    with no traceback."""
    err = capsys.readouterr().err.strip()
    last = err.splitlines()[-1]
    assert last.startswith(f"calnav {command}: error: ") and "Traceback" not in err, err
    assert err.count("error:") == 1, err
    return last


def test_unusable_results_directories_give_one_line_errors(tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    assert main(_objectnav(a_file)) == 2
    assert f"--output {a_file} is a file, not a directory" in _one_line_error(capsys, "objectnav")
    assert main(["tune", "--output", str(a_file), "--episodes", "0:1", "--thresholds", "0.9",
                 "--min-areas", "2", *SMALL]) == 2
    assert "is a file, not a directory" in _one_line_error(capsys, "tune")
    assert main(["calibrate-map", "--output", str(a_file), "study.segmenters=[gt]"]) == 2
    assert "is a file, not a directory" in _one_line_error(capsys, "calibrate-map")
    assert main(["fit-glfs", "--segmenter", "gt", "--output", str(tmp_path / "g.json"), "--work-dir", str(a_file)]) == 2
    assert f"--work-dir {a_file} is a file, not a directory" in _one_line_error(capsys, "fit-glfs")

    for name in ("episodes.jsonl", "config.yaml"):
        d = tmp_path / f"dir_{name}"
        (d / name).mkdir(parents=True)
        assert main(_objectnav(d)) == 2
        assert f"{d / name} is a directory, not a file" in _one_line_error(capsys, "objectnav")


def _read_only_dir(path: Path):
    """``path`` as a read-only directory: a read-only tmpfs when running as root (which ignores
    permission bits), else mode 0555. Returns an undo function, or None if neither works."""
    path.mkdir()
    if os.geteuid() != 0:
        path.chmod(0o555)
        return lambda: path.chmod(0o755)
    if shutil.which("mount") is None or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(path)], capture_output=True).returncode:
        return None
    return lambda: subprocess.run(["umount", str(path)], check=True)


def test_read_only_file_system_gives_a_one_line_error(tmp_path, capsys):
    ro = tmp_path / "ro"
    undo = _read_only_dir(ro)
    if undo is None:
        pytest.skip("cannot make a read-only directory here (root without mount permission)")
    try:
        assert main(_objectnav(ro / "run")) == 2
        assert "cannot write results directory" in _one_line_error(capsys, "objectnav")
        assert main(_objectnav(ro)) == 2  # the directory exists, but cannot be written
        assert "Read-only file system" in _one_line_error(capsys, "objectnav") or os.geteuid() != 0
    finally:
        undo()


def test_run_whose_episodes_all_crash_exits_nonzero_with_the_first_error(tmp_path, capsys, monkeypatch):
    import calnav.eval.objectnav.run as run

    def crash(env, agent, index, video_dir=None, rerun_dir=None):
        raise RuntimeError(f"bad glfs params (episode {index})")

    monkeypatch.setattr(run, "run_one_episode", crash)  # workers=1 runs episodes in this process
    out = tmp_path / "run"
    assert main(_objectnav(out, "0:2")) == 2
    err = _one_line_error(capsys, "objectnav")
    assert "all 2 episodes failed; first error (episode 0): RuntimeError: bad glfs params (episode 0)" in err
    summary = json.loads((out / "summary.json").read_text())  # the records and summary are still written
    assert summary["failed"] == 2


def test_config_check_ignores_neutral_keys_and_force_discards(tmp_path):
    """One meaning everywhere (objectnav and calibrate-map configs alike): resolved dicts are
    compared without run.workers / run.output_dir; --force deletes only the ``discard`` names."""
    from calnav.eval.config import CALIBRATION_SECTIONS, load_config

    for sections, name in ((None, "objectnav"), (CALIBRATION_SECTIONS, "calibrate")):
        kw = {"sections": sections} if sections else {}
        out = tmp_path / name
        with ResultsDir(out, load_config(None, ["run.workers=1"], **kw), discard=("fits", RECORDS)):
            (out / "fits").mkdir()
            (out / RECORDS).write_text("{}\n")
            (out / "keep.txt").write_text("x")
        with ResultsDir(out, load_config(None, ["run.workers=3", "run.output_dir=elsewhere"], **kw)):
            pass  # neutral keys: the same config
        other = load_config(None, ["run.seed=5"], **kw)
        with pytest.raises(ResultsError, match="holds results of a different config"):
            ResultsDir(out, other).open()
        assert (out / "fits").is_dir()
        with ResultsDir(out, other, force=True, discard=("fits", RECORDS)):
            pass
        assert not (out / "fits").exists() and not (out / RECORDS).exists() and (out / "keep.txt").exists()
        assert "seed: 5" in (out / "config.yaml").read_text()



def test_more_houses_in_the_split_resume_the_same_records(run_copy, capsys):
    """A split's house count decides which episodes exist, not what an index holds: the run of
    0:4 with 2 val houses resumes with 3 houses to 0:7, running only 4:7 and keeping the first
    four records as they were; episodes per house do move the indices, so changing them is refused."""
    before = (run_copy / RECORDS).read_text()
    assert main(_objectnav(run_copy, "0:7", "env.dataset.val_scenes=3")) == 0
    after = (run_copy / RECORDS).read_text()
    assert after.startswith(before) and sorted(r["index"] for r in _lines(run_copy)) == list(range(7))
    assert [r["scene"] for r in _lines(run_copy)][-1].endswith("0002")   # the third house's first episode
    assert "val_scenes: 3" in (run_copy / "config.yaml").read_text()
    capsys.readouterr()
    assert main(_objectnav(run_copy, "0:7", "env.dataset.val_scenes=3", "env.dataset.episodes_per_scene=4")) == 2
    assert "different config" in capsys.readouterr().err


def test_a_changed_input_file_under_the_same_config_is_another_run(tmp_path, capsys):
    """Weights replaced in place (same config, same path) are refused on resume, by open and by
    check, naming the file; --force discards; a directory without inputs.json (older calnav) is
    resumed with a warning; the default learned weights and predictor are fingerprinted too."""
    from calnav.eval.config import load_config
    from calnav.eval.inputs import input_files

    params = tmp_path / "glfs.json"
    shutil.copy(REPO_ROOT / "agent" / "weights" / "glfs_learned_rgb.json", params)
    cfg = load_config(None, ["mapping.fusion=glfs", f"mapping.glfs_params={params}"])
    out = tmp_path / "r"
    with ResultsDir(out, cfg):
        (out / RECORDS).write_text("{}\n")
    saved = json.loads((out / "inputs.json").read_text())
    assert saved["mapping.glfs_params"]["path"] == str(params)
    with ResultsDir(out, cfg):
        pass   # same files: resumes
    params.write_text(params.read_text().replace("1.0", "1.5", 1))
    for attempt in (lambda: ResultsDir(out, cfg).open(), lambda: ResultsDir(out, cfg).check()):
        with pytest.raises(ResultsError, match=r"holds results made with other input files: mapping.glfs_params "
                                               rf"\({params}\) changed since"):
            attempt()
    assert (out / RECORDS).exists()
    with ResultsDir(out, cfg, force=True):
        pass
    assert not (out / RECORDS).exists()
    assert json.loads((out / "inputs.json").read_text())["mapping.glfs_params"]["sha256"] != \
        saved["mapping.glfs_params"]["sha256"]
    (out / "inputs.json").unlink()
    capsys.readouterr()
    with ResultsDir(out, cfg):
        pass
    assert "has no inputs.json" in capsys.readouterr().err and (out / "inputs.json").exists()
    (out / "inputs.json").unlink()
    (out / "inputs.json").mkdir()
    with pytest.raises(ResultsError, match=r"inputs.json is not readable JSON \(IsADirectoryError\); remove it"):
        ResultsDir(out, cfg).open()

    files = input_files({"agent": {"segmenter": "learned_rgb", "exploration": "prediction", "predictor_weights": ""},
                         "segmenter": {"weights": ""}, "study": {"segmenters": ["learned_rgbd", "gt"]}})
    assert [p.name for p in files.values()] == ["learned_rgb.pt", "learned_rgbd.pt", "predictor.pt"]
    named = input_files({"agent": {"segmenter": "learned_rgb"}, "segmenter": {"weights": str(params)}})
    assert list(named) == ["segmenter.weights"]



def test_input_fingerprints_follow_what_the_run_reads(tmp_path, monkeypatch):
    """The segmenter section (``segmenter``, in every command's config) decides between a named
    and the default weights; a relative shipped path is found from any working directory, as the
    loaders find it; strings that are not paths never match a file; fit-glfs fingerprints only
    its own segmenter; only files both sides list can differ."""
    from calnav.eval.config import load_config, to_dict
    from calnav.eval.inputs import changed_inputs, input_files

    weights = tmp_path / "mine.pt"
    weights.write_bytes(b"x")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "val").write_text("a stray file named like a split")
    named = input_files(to_dict(load_config(None, ["agent.segmenter=learned_rgb", f"segmenter.weights={weights}",
                                                   "mapping.glfs_params=agent/weights/glfs_learned_rgb.json"])))
    assert set(named) == {"segmenter.weights", "mapping.glfs_params"}
    assert named["mapping.glfs_params"] == REPO_ROOT / "agent" / "weights" / "glfs_learned_rgb.json"
    default = input_files(to_dict(load_config(None, ["agent.segmenter=learned_rgbd"])))
    assert [p.name for p in default.values()] == ["learned_rgbd.pt"]
    only = input_files({"study": {"segmenters": ["learned_rgb", "learned_rgbd"]}, "segmenter": {"weights": ""}},
                       segmenters=("learned_rgb",))
    assert [p.name for p in only.values()] == ["learned_rgb.pt"]
    a, b = {"x": {"sha256": "1"}, "y": {"sha256": "2"}}, {"x": {"sha256": "1"}, "z": {"sha256": "3"}}
    assert changed_inputs(a, b) == [] and changed_inputs(a, {"x": {"sha256": "9"}}) == ["x"]
    assert changed_inputs({"x": "garbage"}, {"x": {"sha256": "1"}}) == ["x"]


def test_a_directory_saved_before_the_trace_key_resumes(tmp_path, capsys):
    """segmenter.trace (bit-identical logits) is a neutral key: a config.yaml written before it
    existed -- and before the segmenter section moved out of ``agent`` -- (and without
    inputs.json) still resumes, with the one warning."""
    import yaml

    from calnav.eval.config import dump_yaml, load_config

    cfg = load_config(None, ["agent.segmenter=gt"])
    out = tmp_path / "old"
    out.mkdir()
    old = yaml.safe_load(dump_yaml(cfg))
    old["agent"]["segmenter_config"] = old.pop("segmenter")   # where it was
    del old["agent"]["segmenter_config"]["trace"]
    (out / "config.yaml").write_text(yaml.safe_dump(old))
    with ResultsDir(out, cfg):
        pass
    assert "has no inputs.json" in capsys.readouterr().err
    with pytest.raises(ResultsError, match=r"use another --work-dir$"):
        ResultsDir(out, load_config(None, ["agent.segmenter=gt", "run.seed=3"]), option="--work-dir",
                   can_force=False).open()


def test_a_directory_of_the_old_segmenter_section_resumes_and_compares(tmp_path, capsys):
    """A results directory whose config.yaml and inputs.json hold the segmenter's settings at
    their old place (``agent.segmenter_config``, eval.config.MOVED_KEYS) is the same run as
    the new form: it resumes without --force and without a note (a stored file, not the
    user's), ``calnav compare`` finds no differing key between it and a new-form run, and a
    weight file changed under its old label is still another run's."""
    import yaml

    from calnav.eval.config import dump_yaml, load_config
    from calnav.eval.stats import METRICS

    weights = tmp_path / "w.pt"
    weights.write_bytes(b"weights")
    cfg = load_config(None, ["agent.segmenter=learned_rgb", f"segmenter.weights={weights}", "run.agent=oracle"])
    new, old = tmp_path / "new", tmp_path / "old"
    for out in (new, old):
        with ResultsDir(out, cfg):
            (out / RECORDS).write_text(json.dumps({"index": 0, "status": "ok", **{m: 1.0 for m in METRICS}}) + "\n")
    stored = yaml.safe_load((old / "config.yaml").read_text())
    stored["agent"]["segmenter_config"] = stored.pop("segmenter")
    (old / "config.yaml").write_text(yaml.safe_dump(stored, sort_keys=False))
    inputs = json.loads((old / "inputs.json").read_text())
    inputs["agent.segmenter_config.weights"] = inputs.pop("segmenter.weights")
    (old / "inputs.json").write_text(json.dumps(inputs))
    capsys.readouterr()
    ResultsDir(old, cfg).check()
    with ResultsDir(old, cfg):
        pass   # resumed: no refusal, no --force
    assert capsys.readouterr().err == ""
    assert yaml.safe_load((old / "config.yaml").read_text()) == yaml.safe_load(dump_yaml(cfg))   # rewritten, new form
    assert main(["compare", str(old), str(new), "--output", str(tmp_path / "cmp")]) == 0
    assert "segmenter" not in (tmp_path / "cmp" / "comparison.md").read_text()   # no key differs
    (old / "config.yaml").write_text(yaml.safe_dump(stored, sort_keys=False))
    (old / "inputs.json").write_text(json.dumps(inputs))
    weights.write_bytes(b"retrained")
    with pytest.raises(ResultsError, match=rf"other input files: segmenter.weights \({weights}\) changed since"):
        ResultsDir(old, cfg).open()


def test_check_finds_a_held_directory_and_another_config_without_writing(tmp_path):
    """ResultsDir.check (calnav map: checked before fusing, opened after) refuses what open would."""
    from calnav.eval.config import load_config

    path = tmp_path / "r"
    held = ResultsDir(path, load_config(None, ["run.seed=1"])).open()
    try:
        with pytest.raises(ResultsError, match=r"in use by another calnav run \(pid \d+\)"):
            ResultsDir(path).check()
    finally:
        held.close()
    before = sorted(p.name for p in path.iterdir())
    with pytest.raises(ResultsError, match="holds results of a different config"):
        ResultsDir(path, load_config(None, ["run.seed=2"])).check()
    ResultsDir(path, load_config(None, ["run.seed=2"]), force=True).check()
    ResultsDir(path, load_config(None, ["run.seed=1"])).check()
    assert sorted(p.name for p in path.iterdir()) == before   # check writes nothing
    ResultsDir(tmp_path / "new" / "dir").check()
    assert not (tmp_path / "new").exists()


def test_config_differences_name_the_first_keys_and_count_the_rest():
    from calnav.eval.results_dir import config_differences

    saved = {"a": {"x": 1, "y": [1, 2]}, "b": 2, "c": 3, "d": 4}
    assert config_differences(saved, {**saved, "b": 5}) == "b: 2 there, 5 here"
    assert config_differences(saved, {"a": {"x": 1, "y": [1, 3]}, "e": 0}) == (
        "a.y: [1, 2] there, [1, 3] here; b: 2 there, (absent) here; c: 3 there, (absent) here; 2 more key(s)")


def test_a_resume_refuses_records_of_other_episodes_under_the_same_indices(run_copy, capsys):
    """Scans (and so the episodes on them) made by another calnav version or on another machine
    place other starts under the same indices: records made on them are refused, never mixed
    with this split's episodes, before anything is written; --force discards and reruns them."""
    records = run_copy / "episodes.jsonl"
    lines = [json.loads(line) for line in records.read_text().splitlines()]
    lines = [r for r in lines if r["index"] != 3]                    # one episode left to run
    elsewhere = next(r for r in lines if r["index"] == 1)
    elsewhere["geodesic_distance"] += 1.25                            # as a scan made elsewhere places it
    records.write_text("".join(json.dumps(r) + "\n" for r in lines))
    before = records.read_text()
    assert main(_objectnav(run_copy)) == 2
    err = _one_line_error(capsys, "objectnav")
    assert f"{run_copy} holds other records: 1 of its 3 recorded episodes up to 4 are not the episodes the val " \
           f"split holds now (episode 1: recorded {elsewhere['episode_id']}" in err
    assert "resuming would mix two datasets (recorded " in err   # the environment the records were made in
    assert err.endswith("; use another --output, or --force to discard them")
    assert records.read_text() == before
    assert main(_objectnav(run_copy, "2:4")) == 2                    # a later range checks the records before it too
    capsys.readouterr()
    assert main(_objectnav(run_copy, "0:4", "--force")) == 0
    got = sorted(_lines(run_copy), key=lambda r: r["index"])
    assert [r["index"] for r in got] == [0, 1, 2, 3]
    assert got[1]["geodesic_distance"] == pytest.approx(elsewhere["geodesic_distance"] - 1.25, abs=1e-12)
    assert main(_objectnav(run_copy)) == 0                            # its own records resume as ever


def test_the_environment_of_each_open_is_kept_and_named_when_records_differ(run_copy, capsys):
    """Each open that writes appends its environment (CPU, Python, package versions) to
    environment.jsonl; records of other episodes are refused naming how the last recorded
    environment differs from this one; --force discards that history with the results."""
    from calnav.common.provenance import environment

    env_file = run_copy / "environment.jsonl"
    history = [json.loads(line) for line in env_file.read_text().splitlines()]
    assert len(history) == 1 and history[0]["packages"] == environment()["packages"]
    assert history[0]["cpu"] == environment()["cpu"] and "numpy" in history[0]["packages"]
    assert main(_objectnav(run_copy)) == 0                                        # a resume: one line more
    assert len(env_file.read_text().splitlines()) == 2
    elsewhere = {**history[0], "date": "2026-01-02T03:04:05+00:00", "cpu": "Other CPU 9000",
                 "packages": {**history[0]["packages"], "numpy": "0.1.0"}}
    with open(env_file, "a") as f:
        f.write(json.dumps(elsewhere) + "\n{torn")                                # a torn last line is skipped
    records = run_copy / "episodes.jsonl"
    lines = [json.loads(line) for line in records.read_text().splitlines()]
    lines[0]["geodesic_distance"] += 1.25
    records.write_text("".join(json.dumps(r) + "\n" for r in lines))
    assert main(_objectnav(run_copy)) == 2
    err = _one_line_error(capsys, "objectnav")
    here = environment()
    assert (f"(recorded 2026-01-02T03:04:05+00:00 (environment.jsonl): cpu Other CPU 9000 there, {here['cpu']} here; "
            f"numpy 0.1.0 there, {here['packages']['numpy']} here); use another --output") in err
    assert main(_objectnav(run_copy, "0:4", "--force")) == 0
    assert len(env_file.read_text().splitlines()) == 1                            # the discarded results' history went too
    lines = [json.loads(line) for line in records.read_text().splitlines()]
    lines[0]["geodesic_distance"] += 1.25
    records.write_text("".join(json.dumps(r) + "\n" for r in lines))
    assert main(_objectnav(run_copy)) == 2
    assert "(environment.jsonl) with the CPU model and package versions of this machine); use" in \
        _one_line_error(capsys, "objectnav")


def test_environment_history_survives_a_torn_line_and_damaged_values(tmp_path):
    """An append after a torn last line starts a line of its own; a damaged entry (packages no
    mapping, a newline in a value) gives a one-line note naming at most MAX_NAMED_DIFFERENCES."""
    from calnav.common.provenance import environment
    from calnav.eval.results_dir import MAX_NAMED_DIFFERENCES

    rd = ResultsDir(tmp_path)
    (tmp_path / "environment.jsonl").write_text('{"date": "torn')
    rd._append_environment()
    assert rd.recorded_environment()["packages"] == environment()["packages"]
    assert rd._environment_note().endswith("with the CPU model and package versions of this machine)")
    damaged = {"date": "d\nx", "cpu": "A\nB", "python": "0", "packages": ["numpy"]}
    with open(tmp_path / "environment.jsonl", "a") as f:
        f.write(json.dumps(damaged) + "\n")
    note = rd._environment_note()
    assert "\n" not in note and "cpu A B there" in note and "recorded d x" in note
    assert note.count(" there, ") == MAX_NAMED_DIFFERENCES and note.endswith(" more)")
