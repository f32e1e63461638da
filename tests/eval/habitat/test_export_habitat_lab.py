"""habitat-lab's own ``ObjectNavDatasetV1`` loads what `calnav export-habitat` writes (the scene
ids under its ``scenes_dir``, the category maps, the goals of every episode), and what
habitat-lab writes back from it reads in calnav as the same episodes. Needs habitat-lab
(``.venv-habitat``; ``make test`` runs it)."""
import numpy as np
import pytest

from tests.conftest import require_habitat

require_habitat()

from calnav.envs.episode_datasets import read_dataset, resolve_scene  # noqa: E402
from calnav.eval.cli import main  # noqa: E402
from tests.habitat_datasets import load_with_habitat_lab, rewrite_with_habitat_lab  # noqa: E402

pytestmark = pytest.mark.habitat

SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3", "run.workers=1"]


def test_habitat_lab_loads_the_export_and_its_rewrite_reads_back_the_same(tmp_path):
    out = tmp_path / "data"
    assert main(["export-habitat", "--split", "val", "--output", str(out), *SMALL]) == 0
    data_path = str(out / "datasets" / "objectnav" / "calnav" / "v1" / "{split}" / "{split}.json.gz")
    scenes_dir = str(out / "scene_datasets")
    hl = load_with_habitat_lab(data_path, "val", scenes_dir)
    mine = read_dataset(data_path, "val")
    assert len(hl.episodes) == len(mine.episodes) == 6
    assert hl.category_to_task_category_id == mine.source.categories
    for h, c in zip(hl.episodes, mine.episodes):   # habitat-lab's order is calnav's
        assert h.scene_id == str(out / "scene_datasets" / c.scene_id)    # joined to its scenes_dir
        assert str(resolve_scene(c.scene_id, scenes_dir)) == h.scene_id
        assert h.object_category == c.object_category and h.goals and len(h.goals) == len(c.goals)
        np.testing.assert_allclose([h.start_position[0], -h.start_position[2]], c.start_position, atol=1e-5)
        assert h.start_position[1] == pytest.approx(c.start_height, abs=1e-5)
    again = read_dataset(rewrite_with_habitat_lab(data_path, "val", scenes_dir, tmp_path / "rewritten"), "val")
    assert [e.scene_id for e in again.episodes] == [h.scene_id for h in hl.episodes]   # absolute paths now
    for a, b in zip(again.episodes, mine.episodes):
        np.testing.assert_allclose(a.start_position, b.start_position, atol=1e-5)   # habitat-lab: 5 decimals
        assert a.object_category == b.object_category
        np.testing.assert_allclose(np.concatenate([g.view_points for g in a.goals]),
                                   np.concatenate([g.view_points for g in b.goals]), atol=1e-5)
