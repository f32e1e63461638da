#!/usr/bin/env bash
# The appearance-lever ablation of learned_rgb (agent/weights/README.md): one small training per
# row on the same frames, each scored on clean, scanned and camera-shifted scanned test frames.
# FRAMES training frames (default 4000); weights go to $WEIGHTS (not shipped), the eval records
# and training cards to agent/weights/ablation/f$FRAMES/.
set -euo pipefail
cd "$(dirname "$0")/../../.."
FRAMES=${FRAMES:-4000}
HERE=agent/weights/ablation/f$FRAMES
WEIGHTS=${WEIGHTS:-/tmp/calnav_ablation}
PY=${PY:-python}
mkdir -p "$WEIGHTS/f$FRAMES" "$HERE"
DATA="data.frames=$FRAMES data.scenes=30 train.epochs=4 train.val_frames=0 train.threads=1"
PHOTO="train.exposure_ev=1 train.white_balance=0.3 train.tint=0.15 train.gamma=0.5 train.vignette=0.4 \
train.motion_blur_prob=0.2 train.shot_noise=12"
JPEG="train.jpeg_prob=0.5"
RECOL="data.recolour_fraction=0.5"
declare -A ROWS=([baseline]="" [photometric]="$PHOTO" [jpeg]="$JPEG" [recolour]="$RECOL" [all]="$PHOTO $JPEG $RECOL")
declare -A EVALS=([clean]="env.dataset.style=clean" [scanned]="env.dataset.style=scanned"
                  [camera]="env.dataset.style=scanned data.eval_appearance=camera")
for row in ${ROWS_ONLY:-baseline photometric jpeg recolour all}; do
  # shellcheck disable=SC2086
  $PY -m calnav.eval.cli train-segmenter --segmenter learned_rgb --output "$WEIGHTS/f$FRAMES/$row.pt" $DATA ${ROWS[$row]}
  cp "$WEIGHTS/f$FRAMES/$row.json" "$HERE/$row.card.json"
  for ev in clean scanned camera; do
    # shellcheck disable=SC2086
    $PY -m calnav.eval.cli eval-segmenter --segmenter learned_rgb --split test --frames 500 \
      --output "$HERE/${row}_$ev.json" segmenter.weights="$WEIGHTS/f$FRAMES/$row.pt" data.scenes=12 ${EVALS[$ev]}
  done
done
