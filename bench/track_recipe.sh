#!/usr/bin/env bash
# The tracker's training recipe on one GPU: an ablation of recipe variants, and the recipe's
# training runs by seed. Run from the repository root after the pip prefix of shared/gpu/README.md.
#
#   bash bench/track_recipe.sh ablate A   (~9.5 min) four variants side by side on the one GPU, 4096 envs each,
#                                          the same wall-clock budget; set A: recipe, actuator gains, no
#                                          filter, the first shipped tracker's action-rate weight (-0.005)
#                                          (`old`, the whole first recipe, is in VARIANT but in no set)
#   bash bench/track_recipe.sh ablate B   (~9.5 min) the recipe without adaptive sampling, with a fixed
#                                          learning rate, without the near-cap term, TF32 products
#   GPUS="0 1 2 3" bash bench/track_recipe.sh ablate A|B
#                                         (~9.5 min, nvidia-h100-x4) the same sets, one variant per GPU at the
#                                          recipe's own size (the controlled single-change ablation of record)
#   bash bench/track_recipe.sh train SEED (~9.5 min) `--preset track --seed SEED` alone on the GPU: the
#                                          figure of record (10 min on one H100, compile included)
#                                          (EXTRA="--env-overrides k=v ..." adds arguments: a candidate)
#   bash bench/track_recipe.sh rsl SEED   (~9.5 min) the tracker on the rsl-rl backend at the field's values
#                                          (`field_cli_flags(8192)`) on the track preset's networks, action
#                                          prior and initial std 0.3 (docs/training.md); EXTRA adds arguments
#                                          (e.g. EXTRA="--rsl-rl.schedule fixed --ppo.schedule fixed
#                                          --ppo.learning-rate 3e-4": rsl-rl's schedule and its brax side)
#   bash bench/track_recipe.sh rsl-fixed SEED (~9.5 min) `--preset track-rsl`: `rsl` with the track preset's
#                                          fixed rate 3e-4, entropy cost 1e-3 and gamma 0.98 in place of the
#                                          field's KL-adaptive rate (its files chatter at 25 Hz), 5e-3 and 0.99:
#                                          files that pass the ship gate, within 20 % of brax's
#                                          errors (docs/performance.md, 2026-11-29)
#   bash bench/track_recipe.sh smoke      CPU check of the script with tiny sizes (smoke-rsl: the rsl part)
#
# $OUT gets runs.tgz (each run's config, metrics.jsonl, final_eval.json, ONNX files, newest checkpoint and
# log) and summary.md
# (per run: held-out MJX evaluation at the end, best iterate, steps, wall time). Evaluate the ONNX files on
# the C MuJoCo sim target here with `bar-deploy eval --policy <run>/policy.onnx --clips heldout`.
set -u
PART=${1:-smoke}
ARG=${2:-A}
OUT=${OUT:-/tmp/track_recipe_out}
WORK=${WORK:-/tmp/track_recipe}
mkdir -p "$OUT" "$WORK"
export PYTHONUNBUFFERED=1
RUNS=$WORK/runs
CACHE=$WORK/jaxcache
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }

# Recipe variants: name -> extra arguments (on top of --preset track).
OLD_ENV="reward.scales.action_rate=-0.005 reward.scales.torque_near_cap=0.0 reward.scales.fingertip_pos=0.0"
OLD_ENV="$OLD_ENV action_filter_hz=null sampling.enabled=false"
declare -A VARIANT=(
  [recipe]=""
  [actuator_gains]="--env-overrides gains=actuator"
  [no_filter]="--env-overrides action_filter_hz=null"
  [weak_action_rate]="--env-overrides reward.scales.action_rate=-0.005"
  [old]="--ppo.schedule fixed --matmul-precision default --network.action-prior none --env-overrides $OLD_ENV"
  [no_sampling]="--env-overrides sampling.enabled=false"
  [fixed_lr]="--ppo.schedule fixed"
  [no_near_cap]="--env-overrides reward.scales.torque_near_cap=0.0"
  [tf32]="--matmul-precision default"
)
SETS_A="recipe actuator_gains no_filter weak_action_rate"
SETS_B="no_sampling fixed_lr no_near_cap tf32"

SIZE=""
PRE=""  # arguments before SIZE (so that the smoke's tiny sizes win over them)
MINUTES=${MINUTES:-8.9}
if [ "$PART" = smoke ] || [ "$PART" = smoke-rsl ]; then
  export JAX_PLATFORMS=cpu
  SIZE="--ppo.num-envs 16 --ppo.batch-size 16 --ppo.num-minibatches 2 --ppo.unroll-length 4 --ppo.num-updates-per-batch 1"
  SIZE="$SIZE --ppo.num-timesteps 256 --eval.num-eval-envs 8 --eval.num-evals 2 --final-eval-envs 8"
  SIZE="$SIZE --network.policy-hidden 16 16 --network.value-hidden 16 16"
  MINUTES=0
  SETS_A="recipe old"
fi

run_one() {  # run_one NAME SEED EXTRA...  (GPU=<index> pins it to one card)
  local name=$1 seed=$2; shift 2
  stamp "start $name (seed $seed, GPU ${GPU:-shared}): $*"
  local pin=""
  [ -n "${GPU:-}" ] && pin="CUDA_VISIBLE_DEVICES=$GPU"
  # shellcheck disable=SC2086
  env $pin timeout -k 5 ${RUN_TIMEOUT:-585} python3 train/ppo.py --preset track --seed "$seed" --run-name "$name" --runs-dir "$RUNS" \
    --compile-cache-dir "$CACHE" --max-minutes "$MINUTES" $PRE $SIZE "$@" > "$WORK/$name.log" 2>&1
  stamp "end $name: exit $?"
}

summary() {
  python3 bench/recipe_summary.py "$RUNS" > "$OUT/summary.md" --keys success_rate joint_error_rad \
    fingertip_error_cm quality/completion_pct quality/cap_share_pct quality/chatter_max_mrad \
    quality/chatter_mean_mrad quality/action_rate --best joint_error_rad fingertip_error_cm \
    quality/completion_pct quality/cap_share_pct quality/chatter_max_mrad
  cat "$OUT/summary.md"
  # Keep each run's newest checkpoint (a failed export must not lose the trained parameters).
  for d in "$RUNS"/*/checkpoints; do
    [ -d "$d" ] && ls -1 "$d"/step_*.msgpack 2>/dev/null | head -n -1 | sed 's/.msgpack$//' | \
      while read -r old; do rm -f "$old.msgpack" "$old.json"; done
  done
  (cd "$WORK" && tar czf "$OUT/runs.tgz" ${NO_CKPT:+--exclude=checkpoints} runs ./*.log 2>/dev/null)
}

case "$PART" in
  ablate|smoke)
    set_names=$SETS_A
    [ "$ARG" = B ] && set_names=$SETS_B
    read -r -a gpus <<< "${GPUS:-}"
    if [ "${#gpus[@]}" -gt 0 ]; then  # one variant per GPU, each at the recipe's size
      [ "$PART" = ablate ] && SIZE="--final-eval-envs 1024"
    else  # side by side on one GPU
      [ "$PART" = ablate ] && SIZE="--ppo.num-envs 4096 --ppo.batch-size 512 --final-eval-envs 1024"
      export XLA_PYTHON_CLIENT_MEM_FRACTION=${MEM:-0.22}
    fi
    i=0
    for v in $set_names; do
      # shellcheck disable=SC2086
      GPU=${gpus[$i]:-} run_one "$v" 0 ${VARIANT[$v]} &
      i=$((i + 1))
      sleep 2
    done
    wait
    ;;
  train)
    # shellcheck disable=SC2086
    run_one "recipe-seed$ARG" "$ARG" --final-eval-envs 1024 ${EXTRA:-}
    ;;
  rsl|rsl-fixed|smoke-rsl)
    if [ "$PART" = rsl-fixed ]; then  # the last --preset wins: track-rsl over run_one's track
      PRE="--preset track-rsl"
      name=rsl-fixed
    else
      # The field's rsl-rl values but not its networks or initial std (the preset's networks and reference
      # prior stay; 0.3 action units: at the field's 1.0 the wrists end at their limits, docs/training.md).
      PRE=$(python3 -c "
from bar_policy.training.rsl_rl.config import field_cli_flags
own = ('network.policy_hidden', 'network.value_hidden', 'network.init_noise_std', 'ppo.update_precision')
print(' '.join(field_cli_flags(8192, leave_out=own)))") || exit 1
      PRE="--backend rsl-rl $PRE --network.init-noise-std 0.3"
      name=rsl
    fi
    PRE="$PRE --final-eval-envs 1024"
    seed=$ARG
    [ "$PART" = smoke-rsl ] && seed=0
    # shellcheck disable=SC2086
    run_one "$name-seed$seed" "$seed" ${EXTRA:-}
    ;;
  *) echo "unknown part $PART (ablate A|B, train SEED, rsl SEED, rsl-fixed SEED, smoke, smoke-rsl)"; exit 2 ;;
esac
summary
stamp done
