#!/usr/bin/env bash
# The agreement records of docs/datasets.md: calnav's houses exported in HM3D's layout and read
# back through env.dataset.data_path, beside calnav's own runs of the same episodes (gt agent).
set -euo pipefail
cd "$(dirname "$0")/../.."
rm -rf runs/export runs/export_scanned runs/export_scanned_hl docs/datasets/roundtrip_val docs/datasets/scanned_val
# clean houses: the file calnav writes
calnav export-habitat --split val --scenes 2 --output runs/export
calnav objectnav --episodes 0:20 --output docs/datasets/roundtrip_val/calnav
calnav objectnav --episodes 0:20 --output docs/datasets/roundtrip_val/file \
    env.dataset.data_path='runs/export/datasets/objectnav/calnav/v1/{split}/{split}.json.gz' \
    env.dataset.scene_dir=runs/export/scene_datasets
calnav compare docs/datasets/roundtrip_val/calnav docs/datasets/roundtrip_val/file --output docs/datasets/roundtrip_val/compare
# a scanned house, its episodes loaded and written again by habitat-lab (.venv-habitat)
calnav export-habitat --split val --scenes 1 --output runs/export_scanned env.dataset.style=scanned
.venv-habitat/bin/python -c "
import sys; sys.path.insert(0, '.')
from pathlib import Path
from tests.habitat_datasets import rewrite_with_habitat_lab
rewrite_with_habitat_lab('runs/export_scanned/datasets/objectnav/calnav/v1/{split}/{split}.json.gz', 'val',
                         'runs/export_scanned/scene_datasets', Path('runs/export_scanned_hl'))"
calnav objectnav --episodes 0:20 --output docs/datasets/scanned_val/calnav env.dataset.style=scanned
calnav objectnav --episodes 0:20 --output docs/datasets/scanned_val/file \
    env.dataset.data_path='runs/export_scanned_hl/{split}/{split}.json.gz' \
    env.dataset.scene_dir=runs/export_scanned/scene_datasets
calnav compare docs/datasets/scanned_val/calnav docs/datasets/scanned_val/file --output docs/datasets/scanned_val/compare
