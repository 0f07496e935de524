#!/usr/bin/env bash
# Table 1 beyond Pong, one game's lane: both inputs x 3 seeds to 5M env steps, one run at a time
# (seed 0's FDR, then its FDR+EDR, then seed 1's...), so that a lane stopped anywhere holds
# comparable seeds of both inputs. The settings are those chosen on Pong (no per-game tuning).
#   sweeps/table1_lane.sh centipede            # starts the lane, or continues it
# Running it again skips the finished runs and continues the one that was stopped from its
# checkpoint (SIGTERM or Ctrl-C saves one; so does every task.checkpoint_every updates).
# Extra arguments are passed to edr-run (say threads=1). Records: results/learning/table1_<game>.
# SEEDS picks the seeds (default "0 1 2"): on a machine with cores to spare, two lanes of one game
# can run beside each other, e.g. SEEDS="0 2" and SEEDS=1, never the same seed twice. INPUTS picks
# the inputs (default "fdr,fdr_edr"): SEEDS=2 INPUTS=fdr and SEEDS=2 INPUTS=fdr_edr split one seed
# over two lanes (its runs' folders are named as the default lane's).
set -euo pipefail
cd "$(dirname "$0")/.."
game="${1:?usage: sweeps/table1_lane.sh GAME [edr-run overrides...]}"
shift
EDR_RUN="${EDR_RUN:-.venv/bin/edr-run}"
inputs="${INPUTS:-fdr,fdr_edr}"
for seed in ${SEEDS:-0 1 2}; do
  "$EDR_RUN" -m experiment=table1_atari "game=$game" "seed=$seed" "task.env.inputs=$inputs" \
    task.env_steps=5000000 "hydra.sweep.dir=results/learning/table1_$game" "$@"
done
