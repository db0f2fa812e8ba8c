#!/usr/bin/env bash
# Reach recipes for the time to a policy: named variants of the gpu preset side by side, one per GPU,
# each a cold run (its own empty compile cache; the shipped autotune seeds apply on an H100) with the
# preset's evaluations (EXTRA="--eval.num-evals 124": one every 327,680 env steps, so that the env steps to
# 95 % are resolved finely).
# BASE="..." goes before each variant's own flags: the tables of 2026-11-27 were measured on the
# preset of their time, BASE="--ppo.batch-size 512 --env-overrides sim_dt=0.002 --eval.num-evals 41"
# (the gpu preset since 2026-11-27 is batch 256 at a 4 ms step: its own variant bs256 at sim_dt=0.004).
# Run from the repository root after the pip prefix of shared/gpu/README.md.
#
#   GPUS="0 1 2 3" bash bench/reach_recipe.sh base envs8192 lr1e-3 upd4   (~3 min, nvidia-h100-x4)
#   bash bench/reach_recipe.sh base                                       (~3 min, one GPU)
#   bash bench/reach_recipe.sh smoke                                      CPU check of the script
#
# Why: a warm start spends about 9 s before learning (imports, model, executable loads) and 1.5-3 s per
# evaluation; the rest is env steps to 95 % over the training speed. Each variant is judged by its env
# steps at 95 % and its steady env steps/s (bench/session_summary.py's table, summary.md in $OUT).
#
# Variants (on top of the gpu preset and BASE; described against the batch-512 preset they were made for):
#   base       the preset                          envs8192  8192 envs, batch_size 1024 (2x the data per iteration)
#   lr1e-3     learning rate 1e-3                  upd4      4 passes over each batch instead of 8
#   mb8        8 minibatches of 1024 (fewer, larger SGD steps)
#   unroll20   20-step unrolls (2x the data per iteration)
#   seed1, seed2  the preset on seeds 1 and 2 (how far seeds differ)
#   ent1e-3    entropy cost 1e-3 instead of 5e-3
#   upd16      16 passes over each batch instead of 8 (twice the SGD steps per env step)
#   bs256      batch_size 256: half the env steps per iteration, the same 128 SGD steps (on half-size
#              minibatches), so twice the SGD steps per env step at the same unroll
#   bs256lr    bs256 with learning rate 1e-3
#   unroll5    5-step unrolls: half the env steps per iteration, the same 128 SGD steps
#   adaptive   rsl-rl's KL-adaptive learning rate from 1e-3 (desired KL 0.01)
#   adabs256   adaptive with bs256
#   s1bs256, s2bs256            bs256 on seeds 1 and 2
#   s1bs256dt4, s2bs256dt4      the same at a 4 ms physics step (--env-overrides sim_dt=0.004)
#   wp0, s1wp0, s2wp0           the wrist posture cost off (weight 0), seeds 0-2: the recipe before it
#   wp03, s1wp03, s2wp03        the wrist posture cost at -0.3 instead of -0.1, seeds 0-2
#   eps0, s1eps0, s2eps0        the normaliser without its variance floor (ppo.obs_std_eps 0), seeds 0-2
#   vt, s1vt, s2vt              value targets and advantages fixed per iteration (ppo.value_targets), seeds 0-2
#   vteps0, s1vteps0, s2vteps0  vt without the variance floor
#   pass, s1pass, s2pass        value targets and advantages fixed per SGD pass (ppo.value_targets pass)
#   passeps0, s1passeps0, s2passeps0  pass without the variance floor
# Two runs per GPU (GPUS="0 1 2 3 0 1 2 3") need XLA_PYTHON_CLIENT_MEM_FRACTION=0.45: then only the env
# steps to 95 % compare, not the env steps/s.
# EXTRA="..." adds arguments to every run; MINUTES (default 2.2) is each run's budget from process start.
# ONNX=1 exports each run's policy (policy.onnx, kept in the archive) for the ship gate (`bar-deploy eval`).
set -u
# shellcheck source=bench/recipe_lib.sh
source "$(dirname "$0")/recipe_lib.sh"
recipe_setup reach_recipe

declare -A VARIANT=(
  [base]=""
  [envs8192]="--ppo.num-envs 8192 --ppo.batch-size 1024"
  [lr1e-3]="--ppo.learning-rate 1e-3"
  [upd4]="--ppo.num-updates-per-batch 4"
  [mb8]="--ppo.num-minibatches 8 --ppo.batch-size 1024"
  [unroll20]="--ppo.unroll-length 20"
  [seed1]="--seed 1"
  [seed2]="--seed 2"
  [ent1e-3]="--ppo.entropy-cost 1e-3"
  [upd16]="--ppo.num-updates-per-batch 16"
  [bs256]="--ppo.batch-size 256"
  [bs256lr]="--ppo.batch-size 256 --ppo.learning-rate 1e-3"
  [unroll5]="--ppo.unroll-length 5"
  [adaptive]="--ppo.schedule adaptive --ppo.learning-rate 1e-3"
  [s1bs256]="--seed 1 --ppo.batch-size 256"
  [s2bs256]="--seed 2 --ppo.batch-size 256"
  [s1bs256dt4]="--seed 1 --ppo.batch-size 256 --env-overrides sim_dt=0.004"
  [s2bs256dt4]="--seed 2 --ppo.batch-size 256 --env-overrides sim_dt=0.004"
  [wp0]="--env-overrides reward.scales.wrist_posture=0"
  [s1wp0]="--seed 1 --env-overrides reward.scales.wrist_posture=0"
  [s2wp0]="--seed 2 --env-overrides reward.scales.wrist_posture=0"
  [wp03]="--env-overrides reward.scales.wrist_posture=-0.3"
  [s1wp03]="--seed 1 --env-overrides reward.scales.wrist_posture=-0.3"
  [s2wp03]="--seed 2 --env-overrides reward.scales.wrist_posture=-0.3"
  [eps0]="--ppo.obs-std-eps 0"
  [s1eps0]="--seed 1 --ppo.obs-std-eps 0"
  [s2eps0]="--seed 2 --ppo.obs-std-eps 0"
  [vt]="--ppo.value-targets iteration"
  [s1vt]="--seed 1 --ppo.value-targets iteration"
  [s2vt]="--seed 2 --ppo.value-targets iteration"
  [vteps0]="--ppo.value-targets iteration --ppo.obs-std-eps 0"
  [s1vteps0]="--seed 1 --ppo.value-targets iteration --ppo.obs-std-eps 0"
  [s2vteps0]="--seed 2 --ppo.value-targets iteration --ppo.obs-std-eps 0"
  [pass]="--ppo.value-targets pass"
  [s1pass]="--seed 1 --ppo.value-targets pass"
  [s2pass]="--seed 2 --ppo.value-targets pass"
  [passeps0]="--ppo.value-targets pass --ppo.obs-std-eps 0"
  [s1passeps0]="--seed 1 --ppo.value-targets pass --ppo.obs-std-eps 0"
  [s2passeps0]="--seed 2 --ppo.value-targets pass --ppo.obs-std-eps 0"
  [adabs256]="--ppo.schedule adaptive --ppo.learning-rate 1e-3 --ppo.batch-size 256"
)
MINUTES=${MINUTES:-2.2}
SIZE="--final-eval-envs 1024 ${BASE:-}"
[ "${ONNX:-0}" = 1 ] || SIZE="$SIZE --no-export-onnx"
names=("$@")
if [ "${1:-smoke}" = smoke ]; then
  export JAX_PLATFORMS=cpu
  SIZE="--preset tiny --ppo.num-timesteps 1024 --final-eval-envs 16 --no-export-onnx"
  MINUTES=0
  names=(base)
fi
check_variants "${names[@]}"

run_one() {  # run_one NAME EXTRA...  (GPU=<index> pins it to one card)
  local name=$1; shift
  train_run "$name" "${RUN_TIMEOUT:-240}" --compile-cache-dir "$WORK/cache_$name" "$@"
}

rm -rf "$WORK"/cache_* "$RUNS"  # a rerun starts afresh (a used run name is refused)
run_variants "${names[@]}"

tar -czf "$OUT/reach_recipe.tgz" -C "$WORK" --exclude='*.msgpack' --exclude='tb' --exclude='cache_*' . 2>/dev/null
runs=()
for v in "${names[@]}"; do runs+=("$RUNS/$v"); done
python3 bench/session_summary.py "${runs[@]}" --out "$OUT/summary.md"
stamp done
