"""docs/habitat.md's peanut parity claim is the committed records': `calnav habitat-benchmark`
and `calnav objectnav` on the same six val episodes give equal records field for field (but the
wall time and the commit), and the page quotes their steps, Success and SPL."""
import json
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
RECORDS = REPO / "docs" / "measured" / "habitat_parity"
OWN = {"wall_time_s", "commit"}   # how long and by which commit a run took: not what it did


def _records(name: str) -> dict[int, dict]:
    lines = (RECORDS / name / "episodes.jsonl").read_text().splitlines()
    return {r["index"]: r for r in map(json.loads, lines)}


def test_the_two_runs_agree_and_the_page_quotes_them():
    habitat, calnav = _records("habitat_benchmark"), _records("calnav_objectnav")
    assert sorted(habitat) == sorted(calnav) == list(range(6))
    for i in habitat:
        a = {k: v for k, v in habitat[i].items() if k not in OWN}
        b = {k: v for k, v in calnav[i].items() if k not in OWN}
        assert a == b, i
    page = (REPO / "docs" / "habitat.md").read_text()
    steps = ", ".join(str(calnav[i]["steps"]) for i in range(6))
    successes = sum(int(calnav[i]["success"]) for i in range(6))
    spl = sum(calnav[i]["spl"] for i in range(6)) / 6
    assert f"(steps {steps} for episodes 0-5;\nSuccess {successes}/6, SPL {spl:.3f} in both)" in page
