"""calnav reads the ObjectNav files habitat-lab's own classes write, as habitat-lab reads them:
the same episodes in the same order, the same goals and view points, the same categories.
Needs habitat-lab (``.venv-habitat``; ``make test`` runs it)."""
import numpy as np
import pytest

from tests.conftest import require_habitat

require_habitat()

from calnav.envs.episode_datasets import read_dataset  # noqa: E402
from tests.habitat_datasets import load_with_habitat_lab, write_habitat_lab_split  # noqa: E402

pytestmark = pytest.mark.habitat

MP3D_CATEGORIES = {name: i for i, name in enumerate(
    ("chair", "table", "picture", "cabinet", "cushion", "sofa", "bed", "chest_of_drawers", "plant", "sink", "toilet",
     "stool", "towel", "tv_monitor", "shower", "bathtub", "counter", "fireplace", "gym_equipment", "seating",
     "clothes"))}


def _scene(name: str, n: int):
    sid = f"mp3d/{name}/{name}.glb"
    episodes = [{"episode_id": i, "scene_id": sid, "start_position": [0.25 * i + 0.123456789, 0.05, -1.5],
                 "start_rotation": [0.0, np.sin(0.3 * i), 0.0, np.cos(0.3 * i)],
                 "object_category": ("chair", "picture")[i % 2], "info": {"geodesic_distance": 2.0 + i},
                 "goals_key": f"{name}.glb_{('chair', 'picture')[i % 2]}"} for i in range(n)]
    goals = {f"{name}.glb_chair": [{"object_id": 3, "object_category": "chair", "position": [1.0, 0.4, -2.0],
                                    "view_points": [(1.0, 0.05, -1.0), (0.5, 0.05, -2.0)]}],
             f"{name}.glb_picture": [{"object_id": 8, "object_category": "picture", "position": [2.0, 1.4, 0.0],
                                      "view_points": [(2.0, 0.05, -0.7)]},
                                     {"object_id": 9, "object_category": "picture", "position": [-2.0, 1.4, 0.0],
                                      "view_points": [(-2.0, 3.05, -0.7)]}]}
    return episodes, goals


def test_files_written_by_habitat_lab_read_as_habitat_lab_reads_them(tmp_path):
    data_path = write_habitat_lab_split(tmp_path / "objectnav_mp3d_v1", "val",
                                        {"zz_second": _scene("zzScene", 3), "aa_first": _scene("aaScene", 2)},
                                        MP3D_CATEGORIES)
    theirs = load_with_habitat_lab(data_path, "val", str(tmp_path / "scene_datasets"))
    ours = read_dataset(data_path, "val")
    assert ours.source.categories == theirs.category_to_task_category_id
    assert len(ours.episodes) == len(theirs.episodes) == 5
    for mine, hab in zip(ours.episodes, theirs.episodes):
        assert hab.scene_id.endswith(mine.scene_id)            # habitat-lab prefixes scenes_dir
        assert mine.object_category == hab.object_category
        assert mine.episode_id.endswith(f":{hab.episode_id}")  # habitat-lab renumbers per file
        x, y, z = hab.start_position                           # habitat-lab's float encoder: 5 decimals
        np.testing.assert_allclose(mine.start_position, [x, -z], atol=0)
        np.testing.assert_allclose(mine.start_rotation, hab.start_rotation, atol=0)
        assert [g.object_id for g in mine.goals] == [int(g.object_id) for g in hab.goals]
        for g_mine, g_hab in zip(mine.goals, hab.goals):
            vps = np.array([v.agent_state.position for v in g_hab.view_points])
            np.testing.assert_allclose(g_mine.view_points, np.stack([vps[:, 0], -vps[:, 2]], 1), atol=0)
    assert [e.scene_id.split("/")[1] for e in ours.episodes] == ["aaScene"] * 2 + ["zzScene"] * 3
