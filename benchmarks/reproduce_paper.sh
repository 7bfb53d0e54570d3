#!/usr/bin/env bash
# Regenerate every table and figure of docs/reproduction.md (see there for what each shows).
# Results go to results/<name> (gitignored); the Markdown tables and PNGs are copied into
# docs/figures/. Usage: benchmarks/reproduce_paper.sh [WORKERS]   (about 30-60 min on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
W="${1:-2}"
R=results/paper
F=docs/figures
mkdir -p "$F"

run() {  # run NAME OUTDIR ARGS...: one experiment, then copy its table and figures
  local name=$1 out=$2; shift 2
  sgloc experiment "$name" --out "$R/$out" --workers "$W" "$@"
  cp "$R/$out/table.md" "$F/$out.md"
  for png in "$R/$out"/*.png; do cp "$png" "$F/$out-$(basename "$png")"; done
}

# Table 1: Airsim, 100 trials, T_error = 5 m, every descriptor x {none, neighbor}; timings are
# the fastest of 3 runs of each (deterministic) trial, in one process.
sgloc experiment table --dataset airsim-guo --trials 100 --threshold 5 --repeats 3 --workers 1 \
  --out "$R/table1-airsim"
cp "$R/table1-airsim/table.md" "$F/table1-airsim.md"
cp "$R/table1-airsim/error_distribution.png" "$F/table1-airsim-error_distribution.png"

# Fig. 4 and 5: RANSAC threshold 1-20 m (30 trials per cell); the PR curves from the same CSV.
run threshold threshold-airsim --dataset airsim-guo --trials 30
run pr pr-airsim --dataset airsim-guo --trials 30 --from-csv "$R/threshold-airsim/trials.csv"

# Fig. 6: overlap sweeps, baseline vs +neighbor (histogram), 100 trials per overlap.
run overlap overlap-kitti00 --dataset kitti00 --trials 100 --overlaps 0.1,0.2,0.3,0.4,0.5
run overlap overlap-kitti00-paper-acceptance --dataset kitti00 --trials 100 \
  --overlaps 0.1,0.2,0.3,0.4,0.5 --set acceptance=false
run overlap overlap-city --dataset synthetic --trials 100 --overlaps 0.1,0.2,0.3,0.5,0.7,0.9
run overlap overlap-city-paper-acceptance --dataset synthetic --trials 100 \
  --overlaps 0.1,0.2,0.3,0.5,0.7,0.9 --set acceptance=false

# The paper's KITTI experiment (whole maps, T_error 5 and 10 m, its acceptance rule), on the
# KITTI 00 two-robot split (A = scans 0-800, B = 3900-4540).
for T in 5 10; do
  run table "kitti00-split-T$T" --dataset kitti00 --trials 100 --threshold "$T" --set tau="$T" \
    --set acceptance=false --descriptors histogram
done

# Fig. 7: the matches of one Airsim trial, and of a city trial at overlap 0.2 (paper's acceptance
# rule) where RANSAC alone returns a wrong transform (seed 3: the first such trial in the CSV).
run matches matches-airsim --dataset airsim-guo --seed 0
run matches matches-city --dataset synthetic --param overlap=0.2 --set acceptance=false --seed 3
