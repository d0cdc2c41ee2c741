#!/usr/bin/env bash
# The merge of a campaign run by examples/slurm/fuzz.sh (see its head), submitted to start after the whole array:
#     sbatch --dependency=afterok:<the array's job id> examples/slurm/merge.sh
# with the same SEED, SHARDS, CAMPAIGN and VENV. Writes $CAMPAIGN/merged (report.md); exit 0 no finding, 1 findings,
# 2 a shard's directory is missing or not a campaign's.
#
#SBATCH --job-name=crosscheck-merge
#SBATCH --cpus-per-task=1
#SBATCH --time=00:15:00
#SBATCH --output=%x-%j.out
set -euo pipefail

SEED=${SEED:-0} SHARDS=${SHARDS:-4}
CAMPAIGN=${CAMPAIGN:-fuzz-$SEED} VENV=${VENV:-.venv}
shards=()
for (( i = 0; i < SHARDS; i++ )); do
    if [[ ! -d $CAMPAIGN/shard-$i ]]; then
        echo "merge.sh: no $CAMPAIGN/shard-$i: run shard $i (sbatch --array=$i examples/slurm/fuzz.sh)" >&2
        exit 2
    fi
    shards+=("$CAMPAIGN/shard-$i")
done
if [[ ! -f $VENV/bin/activate ]]; then
    echo "merge.sh: no virtual environment at $VENV (set it up once: see the head of examples/slurm/fuzz.sh)" >&2
    exit 2
fi
. "$VENV/bin/activate"

crosscheck merge "${shards[@]}" --out "$CAMPAIGN/merged"
