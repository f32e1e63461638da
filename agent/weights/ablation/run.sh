#!/usr/bin/env bash
# The appearance-lever ablation of learned_rgb, or MODEL=learned_rgbd (agent/weights/README.md): one small training per
# row on the same frames, each scored on clean, scanned, camera-shifted scanned and recoloured
# scanned test frames. FRAMES training frames (default 4000); weights go to $WEIGHTS (not shipped),
# the eval records and training cards to agent/weights/ablation/f$FRAMES/. ROWS_ONLY / SETS_ONLY
# pick rows / sets; TRAIN=0 scores a row's existing weights without training it again.
# FRAMES=shipped scores the shipped learned_rgb and learned_rgbd weights on the same sets
# (agent/weights/ablation/shipped/, rows named by the model). MODEL=learned_rgbd writes to
# agent/weights/ablation/rgbd_f$FRAMES/. FRAMES=full trains at the shipped size (20,000 frames, 8
# epochs) on the first 50 train houses (their scans first: calnav scan-houses --splits train
# --houses 50), rows baseline and recolour25 (recolour fraction 0.25), into agent/weights/ablation/full/;
# HOUSES=100 (with FRAMES=full) trains on all 100 train houses, rows recolour25 and recolour10, into
# agent/weights/ablation/full_h100/, beside row shipped: the shipped weights, that size's baseline
# (configs/segmenter.yaml unchanged), scored on the same frames (for learned_rgbd the rows were
# measured against learned_rgbd_base.pt, shipped then). Rows ft_recolour25 / ft_recolour10
# fine-tune those weights (2 epochs, peak lr 1e-3) on frames with that recolour fraction;
# ft does the same without the lever (the control: what 2 more epochs give), ft_fresh on 20,000
# other frames of the same houses (data.seed=1: poses the shipped weights never saw). TEST=full
# scores on 2,000 frames of all 30 test houses (the weights card's held-out set) instead of 500 of
# 12, into <folder>_test2000/ (with TRAIN=0: the rows' weights trained before).
set -euo pipefail
cd "$(dirname "$0")/../../.."
FRAMES=${FRAMES:-4000}
MODEL=${MODEL:-learned_rgb}
HOUSES=${HOUSES:-50}
[[ "$HOUSES" =~ ^[1-9][0-9]*$ ]] || { echo "HOUSES must be a positive integer, got $HOUSES" >&2; exit 2; }
[ "$HOUSES" != 50 ] && [ "$FRAMES" != full ] && { echo "HOUSES is for FRAMES=full, got FRAMES=$FRAMES" >&2; exit 2; }
RUN_FRAMES=f$FRAMES; [ "$FRAMES" = full ] && RUN_FRAMES=full
[ "$FRAMES" = full ] && [ "$HOUSES" != 50 ] && RUN_FRAMES=full_h$HOUSES
case "$MODEL" in learned_rgb) RUN=$RUN_FRAMES ;; learned_rgbd) RUN=rgbd_$RUN_FRAMES ;;
  *) echo "MODEL must be learned_rgb or learned_rgbd, got $MODEL" >&2; exit 2 ;; esac
TEST=${TEST:-12}
case "$TEST" in 12) HERE=agent/weights/ablation/$RUN EVAL="--frames 500 data.scenes=12" ;;
  full) HERE=agent/weights/ablation/${RUN}_test2000 EVAL="--frames 2000 data.scenes=0" ;;
  *) echo "TEST must be 12 or full, got $TEST" >&2; exit 2 ;; esac
WEIGHTS=${WEIGHTS:-/tmp/calnav_ablation}
PY=${PY:-python}
DATA="data.frames=$FRAMES data.scenes=30 train.epochs=4 train.val_frames=0 train.threads=1"
[ "$FRAMES" = full ] && DATA="data.scenes=$HOUSES train.threads=1"   # configs/segmenter.yaml's frames and epochs
PHOTO="train.exposure_ev=1 train.white_balance=0.3 train.tint=0.15 train.gamma=0.5 train.vignette=0.4 \
train.motion_blur_prob=0.2 train.shot_noise=12"
JPEG="train.jpeg_prob=0.5"
RECOL="data.recolour_fraction=0.5"
START=agent/weights/$MODEL.pt; [ "$MODEL" = learned_rgbd ] && START=agent/weights/learned_rgbd_base.pt
FINETUNE="train.init_weights=$START train.epochs=2 train.lr=1e-3"   # from the weights the rows were measured against
declare -A ROWS=([baseline]="" [photometric]="$PHOTO" [jpeg]="$JPEG" [recolour]="$RECOL" [all]="$PHOTO $JPEG $RECOL"
                 [recolour25]="data.recolour_fraction=0.25" [recolour10]="data.recolour_fraction=0.1"
                 [ft_recolour25]="$FINETUNE data.recolour_fraction=0.25" [ft_recolour10]="$FINETUNE data.recolour_fraction=0.1"
                 [ft]="$FINETUNE" [ft_fresh]="$FINETUNE data.seed=1")
declare -A EVALS=([clean]="env.dataset.style=clean" [scanned]="env.dataset.style=scanned"
                  [camera]="env.dataset.style=scanned data.eval_appearance=camera"
                  [recoloured]="env.dataset.style=scanned data.eval_appearance=recolour")
DEFAULT_ROWS="baseline photometric jpeg recolour all"
[ "$FRAMES" = shipped ] && DEFAULT_ROWS="learned_rgb learned_rgbd" && HERE=agent/weights/ablation/shipped
[ "$FRAMES" = full ] && DEFAULT_ROWS="baseline recolour25"
[ "$FRAMES" = full ] && [ "$HOUSES" != 50 ] && DEFAULT_ROWS="shipped recolour25 recolour10"
mkdir -p "$WEIGHTS/$RUN" "$HERE"
for row in ${ROWS_ONLY:-$DEFAULT_ROWS}; do
  model=$MODEL weights="segmenter.weights=$WEIGHTS/$RUN/$row.pt"
  [ "$FRAMES" = shipped ] && model=$row weights=""   # the shipped weights are the segmenter's default
  trained=1; { [ "$FRAMES" = shipped ] || [ "$row" = shipped ]; } && trained=0 weights=""
  [ "$row" = shipped ] && [ "$MODEL" = learned_rgbd ] && weights="segmenter.weights=$START"   # the rows' reference
  if [ "${TRAIN:-1}" != 0 ] && [ $trained = 1 ]; then
    # shellcheck disable=SC2086
    $PY -m calnav.eval.cli train-segmenter --segmenter "$MODEL" --output "$WEIGHTS/$RUN/$row.pt" $DATA ${ROWS[$row]}
  fi
  [ $trained = 1 ] && cp "$WEIGHTS/$RUN/$row.json" "$HERE/$row.card.json"   # the training card beside its scores
  for ev in ${SETS_ONLY:-clean scanned camera recoloured}; do
    # shellcheck disable=SC2086
    $PY -m calnav.eval.cli eval-segmenter --segmenter "$model" --split test $EVAL \
      --output "$HERE/${row}_$ev.json" $weights ${EVALS[$ev]}
  done
done
