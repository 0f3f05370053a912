#!/usr/bin/env bash
# The README's main job on a shipped room: render -> train SpotlessGS -> relight -> evaluate (with SfM).
# Rerunning resumes: finished frames and a finished training run are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOM=${ROOM:-bedroom}
DATA=data/$ROOM
RUN=runs/$ROOM
THREADS=${THREADS:-$(nproc)}

spotless-sim render --scene "scenes/$ROOM/house.json" --out "$DATA" --frames 60 --width 160 --height 120 --samples 16
if [ ! -f "$RUN/train_summary.json" ]; then
  RESUME=""
  { [ -f "$RUN/checkpoints/last.safetensors" ] || [ -f "$RUN/checkpoints/last.pt" ]; } && RESUME="--resume"
  spotless train --data "$DATA" --out "$RUN" --model spotless --preset quick --threads "$THREADS" $RESUME
fi
spotless relight "$RUN" --quiet > /dev/null
spotless eval "$RUN" --sfm --threads "$THREADS" --quiet
echo "Report: $RUN/eval/results.md (figures in $RUN/eval/figures/, relit images in $RUN/relit/)"
