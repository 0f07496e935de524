#!/usr/bin/env bash
# Table 1 beyond Pong, a lane: both inputs x 3 seeds to 5M env steps for one game or several, one
# run at a time, seed-major (seed 0 of every game named, then seed 1, ...; each seed's FDR, then
# its FDR+EDR), so that a lane stopped anywhere holds comparable seeds of both inputs and of
# every game. The settings are those chosen on Pong (no per-game tuning).
#   sweeps/table1_lane.sh centipede                      # starts the lane, or continues it
#   sweeps/table1_lane.sh mspacman qbert seaquest threads=1
# Running it again skips the finished runs and continues the one that was stopped from its
# checkpoint (SIGTERM or Ctrl-C saves one; so does every task.checkpoint_every updates).
# Arguments with '=' are passed to edr-run (say threads=1). Records: results/learning/table1_<game>.
# SEEDS picks the seeds (default "0 1 2"): on a machine with cores to spare, two lanes can run
# beside each other, e.g. SEEDS="0 2" and SEEDS=1, never the same run twice. INPUTS picks the
# inputs (default "fdr,fdr_edr"): INPUTS=fdr and INPUTS=fdr_edr split each seed over two lanes
# (their runs' folders are named as the default lane's).
set -euo pipefail
cd "$(dirname "$0")/.."
games=()
overrides=()
for arg in "$@"; do
  if [[ "$arg" == *=* ]]; then overrides+=("$arg"); else games+=("$arg"); fi
done
if [[ ${#games[@]} -eq 0 ]]; then
  echo "usage: sweeps/table1_lane.sh GAME [GAME...] [edr-run overrides...]" >&2
  exit 2
fi
seeds="${SEEDS-0 1 2}"
if [[ -z "${seeds// /}" ]]; then
  echo "sweeps/table1_lane.sh: SEEDS is empty: name at least one seed (say SEEDS=0)" >&2
  exit 2
fi
EDR_RUN="${EDR_RUN:-.venv/bin/edr-run}"
inputs="${INPUTS:-fdr,fdr_edr}"
for seed in $seeds; do
  for game in "${games[@]}"; do
    "$EDR_RUN" -m experiment=table1_atari "game=$game" "seed=$seed" "task.env.inputs=$inputs" \
      task.env_steps=5000000 "hydra.sweep.dir=results/learning/table1_$game" "${overrides[@]}"
  done
done
