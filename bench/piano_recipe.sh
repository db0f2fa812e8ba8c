#!/usr/bin/env bash
# The piano's training runs: named variants of `--preset piano`, one per GPU, each returned as
# one archive (a device call returns at most 8 files: 2026-11-26 lost a run's policy to that limit).
# Run from the repository root after the pip prefix of shared/gpu/README.md.
#
#   GPUS="0 1" bash bench/piano_recipe.sh preset accel   (~9 min, nvidia-h100-x2) the named variants side
#                                                        by side, one per GPU, each at the preset's size
#   bash bench/piano_recipe.sh preset                    (~9 min, one GPU) one variant
#   bash bench/piano_recipe.sh smoke                     CPU check of the script with tiny sizes
#
# Variants (on top of `--preset piano`, i.e. fixed LR 1e-4 after 10 iterations of critic warm-up):
#   preset   the preset alone (seed 0)         seed1    the preset, seed 1
#   accel    action_accel -0.5, near-cap -1.0 (the 2026-11-26 run nc1)
#   lr3e-4   learning rate 3e-4 (the 2026-11-26 run wA)
# EXTRA="..." adds arguments to every run; MINUTES (default 7.2) is each run's training budget.
#
# $OUT gets <variant>.tgz (config, metrics.jsonl, final_eval.json, ONNX files, log; no checkpoints) and
# summary.md (MJX F1, precision, recall, caps, chatter at the end). Score the files here on the sim target
# and the emulated bus: `bar-deploy eval --policy <run>/policy.onnx` and
# `python bench/piano_prior.py --out <run>/policy.onnx --no-write --eval sim bus`.
set -u
# shellcheck source=bench/recipe_lib.sh
source "$(dirname "$0")/recipe_lib.sh"
recipe_setup piano_recipe

declare -A VARIANT=(
  [preset]=""
  [seed1]="--seed 1"
  [accel]="--env-overrides reward.scales.action_accel=-0.5 reward.scales.torque_near_cap=-1.0"
  [lr3e-4]="--ppo.learning-rate 3e-4"
)
MINUTES=${MINUTES:-7.2}
SIZE="--final-eval-envs 512"
names=("$@")
if [ "${1:-smoke}" = smoke ]; then
  export JAX_PLATFORMS=cpu
  SIZE="--ppo.num-envs 8 --ppo.batch-size 8 --ppo.num-minibatches 2 --ppo.unroll-length 4"
  SIZE="$SIZE --ppo.num-updates-per-batch 1 --ppo.num-timesteps 128 --ppo.actor-warmup-iterations 1"
  SIZE="$SIZE --eval.num-eval-envs 4 --eval.num-evals 2 --final-eval-envs 4"
  SIZE="$SIZE --network.policy-hidden 16 16 --network.value-hidden 16 16"
  MINUTES=0
  names=(preset)
fi
check_variants "${names[@]}"

run_one() {  # run_one NAME EXTRA...  (GPU=<index> pins it to one card)
  local name=$1; shift
  train_run "$name" "${RUN_TIMEOUT:-575}" --preset piano "$@"
  mkdir -p "$RUNS/$name" && cp "$WORK/$name.log" "$RUNS/$name/log.txt"
  (cd "$RUNS" && tar czf "$OUT/$name.tgz" --exclude=checkpoints --exclude=tb "$name")
}

run_variants "${names[@]}"

python3 bench/recipe_summary.py "$RUNS" > "$OUT/summary.md" --keys f1 precision recall \
  quality/completion_pct quality/cap_share_pct quality/chatter_max_mrad --best f1
cat "$OUT/summary.md"
stamp done
