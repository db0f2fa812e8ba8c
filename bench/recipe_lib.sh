#!/usr/bin/env bash
# Sourced by bench/piano_recipe.sh and bench/reach_recipe.sh: the variant check and the side-by-side runs.
# The sourcing script calls recipe_setup first, then defines VARIANT (an associative array: name -> extra
# arguments), MINUTES and SIZE, and run_one NAME EXTRA... (GPU=<index> pins it to one card), which calls
# train_run.

recipe_setup() {  # recipe_setup NAME: OUT (default /tmp/NAME_out), WORK (/tmp/NAME), RUNS=$WORK/runs, the clock
  OUT=${OUT:-/tmp/$1_out}
  WORK=${WORK:-/tmp/$1}
  RUNS=$WORK/runs
  mkdir -p "$OUT" "$WORK"
  export PYTHONUNBUFFERED=1
  T0=$(date +%s)
  # Bytecode for what is on PYTHONPATH: a pip install writes it, the lent machine's --no-compile prefix
  # does not (the warm run's imports 3.4 -> 2.4 s on an H100 machine, 2026-11-27).
  [ -z "${PYTHONPATH:-}" ] || python3 -m compileall -q -j 0 ${PYTHONPATH//:/ } > /dev/null 2>&1 || true
}

stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }

gpu_pin() {  # the environment assignment that pins a run to $GPU (nothing when GPU is unset)
  if [ -n "${GPU:-}" ]; then echo "CUDA_VISIBLE_DEVICES=$GPU"; fi
}

train_run() {  # train_run NAME TIMEOUT_S ARGS...: train/ppo.py as run NAME in $RUNS, on $GPU, log $WORK/NAME.log
  local name=$1 t=$2; shift 2
  stamp "start $name (GPU ${GPU:-all}): $*"
  # shellcheck disable=SC2046,SC2086
  env $(gpu_pin) timeout -k 5 "$t" python3 train/ppo.py --run-name "$name" --runs-dir "$RUNS" \
    --max-minutes "$MINUTES" $SIZE "$@" ${EXTRA:-} > "$WORK/$name.log" 2>&1
  stamp "end $name: exit $?"
}

check_variants() {  # check_variants NAME...: exit 2 naming the valid variants if one is unknown
  local v
  for v in "$@"; do
    [ -n "${VARIANT[$v]+x}" ] || { echo "unknown variant $v (${!VARIANT[*]}, or smoke)"; exit 2; }
  done
}

run_variants() {  # run_variants NAME...: run_one NAME ${VARIANT[NAME]} for each, side by side, on $GPUS in turn
  local gpus i=0 v
  read -r -a gpus <<< "${GPUS:-}"
  for v in "$@"; do
    # shellcheck disable=SC2086
    GPU=${gpus[$i]:-} run_one "$v" ${VARIANT[$v]} &
    i=$((i + 1))
    sleep 2
  done
  wait
}
