#!/usr/bin/env bash
# Sourced by bench/piano_recipe.sh and bench/reach_recipe.sh: the variant check and the side-by-side runs.
# The sourcing script defines VARIANT (an associative array: name -> extra arguments) and
# run_one NAME EXTRA... (GPU=<index> pins it to one card).

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
