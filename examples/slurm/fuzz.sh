#!/usr/bin/env bash
# A crosscheck fuzzing campaign on a Slurm cluster: one shard per task of this job array; examples/slurm/merge.sh,
# submitted to start after the whole array, combines the shards (docs/campaigns.md, "Campaigns on many machines").
#
# Once, on a login node, from the repository root (a Python 3.11 or newer: `module load python` on many clusters):
#     python3 -m venv .venv && . .venv/bin/activate && pip install -e .
# A campaign, from the repository root (settings below; give both jobs the same ones):
#     export SEED=7 MINUTES=30
#     jobid=$(sbatch --parsable examples/slurm/fuzz.sh)
#     sbatch --dependency=afterok:${jobid%%;*} examples/slurm/merge.sh
# The merge job starts when every shard has ended well (a shard with findings ends well: findings are the merge's
# to report), writes $CAMPAIGN/merged/report.md and exits 1 when the campaign has findings.
#
# Settings (environment variables; sbatch passes the submitting shell's on):
#     SEED      campaign seed (default 0)
#     SHARDS    shards: the array is 0..SHARDS-1 (default 4, as --array below; for 8: SHARDS=8 sbatch --array=0-7 ...)
#     MINUTES   minutes per shard (default 30; keep --time about 15 minutes above it: the chunks in flight finish)
#     EXAMPLES  instead of MINUTES: examples over all shards (a bounded campaign: same seed, same report)
#     OPTIONS   more `crosscheck fuzz` options, e.g. "--constraints always --max-bodies 6"
#     CAMPAIGN  campaign directory (default fuzz-$SEED): shard i in $CAMPAIGN/shard-i, the merge in $CAMPAIGN/merged
#     VENV      the virtual environment (default .venv)
#     WORKERS   worker processes per shard (default: the task's CPUs, --cpus-per-task)
# A shard that did not end well (time limit, node failure) resumes from its directory when run again, e.g.
# `sbatch --array=2 examples/slurm/fuzz.sh` with the same settings; then submit the merge again, after that job.
#
#SBATCH --job-name=crosscheck-fuzz
#SBATCH --array=0-3
#SBATCH --cpus-per-task=2
#SBATCH --time=00:45:00
#SBATCH --output=%x-%A_%a.out
set -euo pipefail

SEED=${SEED:-0} SHARDS=${SHARDS:-4} MINUTES=${MINUTES:-30} EXAMPLES=${EXAMPLES:-} OPTIONS=${OPTIONS:-}
CAMPAIGN=${CAMPAIGN:-fuzz-$SEED} VENV=${VENV:-.venv} WORKERS=${WORKERS:-${SLURM_CPUS_PER_TASK:-1}}
shard=${SLURM_ARRAY_TASK_ID:?not a task of a job array: submit with sbatch (--array=0-$((SHARDS - 1)))}
if (( shard >= SHARDS )); then
    echo "fuzz.sh: task $shard of an array beyond SHARDS=$SHARDS: give --array=0-$((SHARDS - 1))" >&2
    exit 2
fi
if [[ ! -f $VENV/bin/activate ]]; then
    echo "fuzz.sh: no virtual environment at $VENV (set it up once: see the head of this script)" >&2
    exit 2
fi
. "$VENV/bin/activate"

budget=(--minutes "$MINUTES")
if [[ -n $EXAMPLES ]]; then budget=(--examples "$EXAMPLES"); fi
set -f   # OPTIONS is split into words, never expanded as file names
status=0
crosscheck fuzz --seed "$SEED" --shard "$shard/$SHARDS" "${budget[@]}" --workers "$WORKERS" \
    --out "$CAMPAIGN/shard-$shard" $OPTIONS || status=$?
# 0 no finding, 1 findings (the merge job reports them); anything else is an error
exit $(( status <= 1 ? 0 : status ))
