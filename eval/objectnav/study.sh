#!/usr/bin/env bash
# The ObjectNav comparison of docs/objectnav_study.md (the paper's Table II): for each segmenter and map type, tune
# the goal threshold on val episodes $TUNE (a best threshold on the grid's edge extends the
# grid, `--extend 2`), then evaluate the tuned config on the disjoint range $EVAL; GLFS is also
# evaluated with the uncertainty-aware agent (at GLFS's tuned threshold), and so is RBU (at its
# own), the control that tells the agent's share of that gain from the calibration's.
# Every step is resumable: rerun the script to continue after an interruption.
#   usage: eval/objectnav/study.sh   (env: OUT, TUNE, EVAL, THRESHOLDS, THRESHOLDS_<segmenter>,
#                                     SEGMENTERS, CALNAV, RUN)
# RUN: extra `run.*` overrides for every command, e.g. RUN="run.backend=ray run.ray_address=auto"
# to run every tuning grid and evaluation as Ray tasks on a cluster (see docs/ray.md).
set -euo pipefail
OUT=${OUT:-runs/study}
TUNE=${TUNE:-0:100}            # tuning episodes (val), an A:B range
EVAL=${EVAL:-100:300}          # evaluation episodes (val), disjoint from TUNE
THRESHOLDS=${THRESHOLDS:-0.5,0.7,0.9}  # goal confidence thresholds tried
# gt's per-pixel confidence is 0.9 by construction (agent.segmenter_config.gt_confidence), so
# a threshold of 0.9 could only reject true detections: its grid stays below it (the edge rule
# may still go above).
THRESHOLDS_gt=${THRESHOLDS_gt:-0.5,0.7,0.85}
SEGMENTERS=${SEGMENTERS:-learned_rgb gt}
CALNAV=${CALNAV:-.venv/bin/calnav}
# 160x120 = the mapping resolution the agent subsamples 640x480 to, and the segmenters' training
# resolution: same information, 1.6x faster episodes (docs/objectnav_study.md, "Sensor resolution").
# shellcheck disable=SC2206
RUN=(${RUN:-})
COMMON=(env.resolution=160x120 "${RUN[@]}")

map_overrides() {  # $1 segmenter, $2 map -> overrides selecting the map
  case $2 in
    ndf) echo "agent.map_type=ndf" ;;
    glfs) echo "mapping.fusion=glfs mapping.glfs_params=agent/weights/glfs_$1.json" ;;
    *) echo "mapping.fusion=$2" ;;
  esac
}

for seg in $SEGMENTERS; do
  thresholds_var="THRESHOLDS_$seg"
  thresholds=${!thresholds_var:-$THRESHOLDS}
  for map in ndf rbu averaging glfs; do
    tune_dir=$OUT/tune/$seg/$map
    # shellcheck disable=SC2046
    $CALNAV tune --episodes "$TUNE" --thresholds "$thresholds" --extend 2 --min-areas 4 --metric spl \
      --output "$tune_dir" "${COMMON[@]}" agent.segmenter="$seg" $(map_overrides "$seg" "$map")
    $CALNAV objectnav --agent peanut --config "$tune_dir/best.yaml" --episodes "$EVAL" \
      --output "$OUT/eval/$seg/$map" "${RUN[@]}"
  done
  for map in glfs rbu; do
    best=$OUT/tune/$seg/$map/best.yaml
    # the uncertainty-aware agent verifies detections in [agent.uncertain_low, tuned threshold):
    # at a tuned threshold at or below uncertain_low that band is empty (calnav refuses the config)
    t=$(awk '$1 == "goal_threshold:" {print $2}' "$best")
    low=$(awk '$1 == "uncertain_low:" {print $2}' "$best")
    if awk -v t="$t" -v low="$low" 'BEGIN {exit !(t <= low)}'; then
      echo "study: no ${map}_uncertainty row for $seg: tuned goal_threshold $t <= agent.uncertain_low $low"
      continue
    fi
    $CALNAV objectnav --agent peanut --config "$best" --episodes "$EVAL" \
      --output "$OUT/eval/$seg/${map}_uncertainty" agent.uncertainty_aware=true "${RUN[@]}"
  done
done
