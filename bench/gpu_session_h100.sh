#!/usr/bin/env bash
# The nvidia-h100-x1 measurements of training at scale, in two calls of under 10 minutes each (argument = part):
#
#   startup  (~7 min, 9.7 at worst): cold start on an empty compilation cache -> the same command again (warm) ->
#                      raw env throughput at the training batch (bench/mjx_throughput.py, harness c, 4096)
#                      -> where an iteration's time goes (bench/train_breakdown.py); COLD_WARM_ONLY=1
#                      stops after the warm run (~4.5 min). Since 2026-11-27 the cold run gets the shipped
#                      autotune seed and the warm one the executable cache (both defaults on a GPU)
#   rsl      (~8 min): the rsl-rl backend, --max-minutes 5, same env at the field's rsl-rl values
#                      (--preset rsl; RSL_PRESET=gpu for brax's), then where an rsl-rl iteration's time
#                      goes (bench/rsl_rl_profile.py, same preset; NO_PROFILE=1: not)
#   flags    (~4 min): two cold starts in one call (compile time varies between hosts by ~25 s, so the
#                      baseline runs beside the variant): XLA's defaults, then XLA_FLAGS=$FLAGS (default: no
#                      autotuning, compilation over 16 threads; flags XLA refuses are left out); then
#                      bench/rsl_rl_profile.py (NO_PROFILE=1: not)
#   seeds    (~3.5 min a preset): XLA autotune seeds for more presets (training.startup.autotune): per preset in
#                      $SEED_PRESETS (default "rsl track"; gpu or piano in a call of their own), a cold run on its own
#                      empty cache without the shipped seed, then bench/autotune_seed.py packs that cache's
#                      autotune results into $OUT (<gpu>-jaxlib-<v>-<preset>.tar.gz/.json: copy both to
#                      bar_policy/data/autotune/)
#   loadflags (~6 min): what XLA flags do to a warm start's executable loads: a cold and a warm run on XLA's
#                      defaults, then a cold and a warm run with XLA_FLAGS=$LOAD_FLAGS (default
#                      --xla_gpu_experimental_aot_compiled_thunks=true: the serialised executable holds its
#                      thunks, so a load need not regenerate them), each pair on its own empty cache; flags
#                      XLA refuses are left out, as in flags. jaxlib 0.11.2 refuses that default (removed:
#                      docs/training.md, "What a warm load still costs"): pass LOAD_FLAGS there
#   update   (~3 min): what an Adam step of the update costs (bench/update_scaling.py, synthetic data, the
#                      trainer's CONCURRENT schedule): per-leaf Adam with a kernel profile of one update
#                      call (its 40 costliest kernels), then each variant in $UPDATE_VARIANTS (default: Adam
#                      over one flat vector; cuBLAS instead of Triton for the matmuls), one process each;
#                      $OUT/summary_update.md holds the rows, $OUT/update_profile.md the profile
#   precision (~7 min): float32 SGD passes (--ppo.update-precision run) against $UPDATE_PRECISION (default
#                      tensorfloat32, the gpu preset's since 2026-11-28: tensor cores, physics and rollout at
#                      float32), on one compile cache: base_s0 (cold), prec_s0..2, base_s1 (warm but for the update),
#                      ONNX exported; $OUT/<run>.onnx for the ship gate (`bar-deploy eval`)
#   prealloc (~5 min): jax's GPU memory preallocation (XLA_PYTHON_CLIENT_PREALLOCATE=true: 75 % of the
#                      device at the first transfer, the model build's 1.5-2.4 s on an H200, 2026-11-29 to 2026-12-01)
#                      against the pool grown on demand (false, the trainer's default since 2026-12-01), the
#                      default command cold then warm each, alternated on one host (A cold, B cold, A warm,
#                      B warm; PREALLOC_FIRST=false runs B first), each pair on its own empty cache
#   smoke             : CPU logic check of startup and rsl with tiny sizes (not for the GPU); smoke-loadflags,
#                      smoke-update, smoke-precision: the same for loadflags, update, precision
#
# Every training run is `python3 train/ppo.py` with the default (gpu) preset, a wall-clock budget
# (--max-minutes, from process start) and no ONNX export; time to 95 % is counted from process start.
# Each step has its own timeout. Work goes to $WORK; $OUT gets 2 files per part: summary_<part>.md (the
# table printed last) and h100_<part>.tgz (logs, metrics, configs).
#
# Usage (repository root, after the pip prefix of /work/shared/gpu/README.md):
#   bash bench/gpu_session_h100.sh startup
#   bash bench/gpu_session_h100.sh rsl
set -u
PART=${1:-startup}
OUT=${OUT:-/tmp/session_h100_out}
WORK=${WORK:-/tmp/session_h100}
mkdir -p "$OUT" "$WORK"
export PYTHONUNBUFFERED=1
T0=$(date +%s)
# Bytecode for what is on PYTHONPATH: a pip install writes it, the lent machine's --no-compile prefix does
# not (the warm run's imports 3.4 -> 2.4 s on an H100 machine, 2026-11-27).
[ -z "${PYTHONPATH:-}" ] || python3 -m compileall -q -j 0 ${PYTHONPATH//:/ } > /dev/null 2>&1 || true
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
CACHE=$WORK/jaxcache
RUNS=$WORK/runs
SMOKE=""
TS=1  # timeout scale: a CPU compiles the same programs several times slower
if [ "$PART" = smoke ] || [ "${PART#smoke-}" != "$PART" ]; then  # smoke-<part>: one part, tiny sizes
  export JAX_PLATFORMS=cpu
  SMOKE="--preset tiny --ppo.num-timesteps 2048 --final-eval-envs 16"
  TS=6
fi
# TRAIN_ARGS: more arguments for every training run (e.g. "--env-overrides sim_dt=0.004"); EXPORT_ONNX=1 keeps
# the ONNX export (to gate the policy afterwards).
NO_EXPORT=--no-export-onnx
[ -n "${EXPORT_ONNX:-}" ] && NO_EXPORT=""
COMMON="--runs-dir $RUNS $NO_EXPORT --final-eval-envs 1024 $SMOKE ${TRAIN_ARGS:-}"

ppo() {  # ppo NAME TIMEOUT_S ARGS...
  local name=$1 t=$2; shift 2
  stamp "train $name: $*"
  timeout -k 10 $((t * TS)) python3 train/ppo.py --run-name "$name" $COMMON "$@" > "$WORK/$name.log" 2>&1
  stamp "train $name exit $?"
  grep -v "^WARNING\|^I0000\|^W0000" "$WORK/$name.log" | grep -A16 "^start-up" | head -n 18
}

startup() {
  rm -rf "$CACHE"
  local runs=("$RUNS/cold" "$RUNS/warm") app=(--append "$WORK/raw_env.md" "$WORK/breakdown.md")
  ppo cold 230 --compile-cache-dir "$CACHE" --max-minutes "${COLD_MIN:-2.6}"
  finish startup "${runs[@]}" "${app[@]}" > /dev/null  # after every step: a killed call still returns it
  ppo warm 120 --compile-cache-dir "$CACHE" --max-minutes "${WARM_MIN:-1.4}"
  finish startup "${runs[@]}" "${app[@]}" > /dev/null
  if [ -n "${COLD_WARM_ONLY:-}" ]; then finish startup "${runs[@]}"; return; fi
  stamp "raw env throughput (harness c, training batch)"
  local b=4096 extra=""
  [ -n "$SMOKE" ] && b=16 && extra="--min-time 1 --min-iters 2"
  timeout -k 10 $((100 * TS)) python3 bench/mjx_throughput.py --harness c --batches $b --no-diagnose $extra \
    --out "$WORK/raw_env.md" > "$WORK/raw_env.log" 2>&1
  stamp "raw env exit $?"
  finish startup "${runs[@]}" "${app[@]}" > /dev/null
  stamp "train breakdown"
  local bd=""
  [ -n "$SMOKE" ] && bd="--preset tiny --iters 1"
  JAX_COMPILATION_CACHE_DIR=$CACHE timeout -k 10 $((120 * TS)) python3 bench/train_breakdown.py $bd \
    --out "$WORK/breakdown.md" > "$WORK/breakdown.log" 2>&1
  stamp "breakdown exit $?"
  tail -n 3 "$WORK/breakdown.log"
  finish startup "${runs[@]}" "${app[@]}"
}

rsl() {
  # --preset rsl: the gpu preset at the field's rsl-rl values (RSL_PRESET=gpu: brax's values on rsl-rl)
  ppo rsl 450 --compile-cache-dir "$CACHE" --preset "${RSL_PRESET:-rsl}" --backend rsl-rl --max-minutes "${RSL_MIN:-5}"
  grep -v "^WARNING" "$WORK/rsl.log" | grep "steps/s" | tail -n 3
  finish rsl "$RUNS/rsl" > /dev/null
  [ -n "${NO_PROFILE:-}" ] && { finish rsl "$RUNS/rsl"; return; }
  stamp "rsl-rl profile"
  local pr="--preset ${RSL_PRESET:-rsl}"
  [ -n "$SMOKE" ] && pr="--preset tiny --iters 1"
  JAX_COMPILATION_CACHE_DIR=$CACHE timeout -k 10 $((150 * TS)) python3 bench/rsl_rl_profile.py $pr \
    --out "$WORK/rsl_profile.md" > "$WORK/rsl_profile.log" 2>&1
  stamp "rsl-rl profile exit $?"
  finish rsl "$RUNS/rsl" --append "$WORK/rsl_profile.md"
}

flags() {
  # 2026-11-26: jax 0.11.2 aborts on --xla_gpu_enable_llvm_module_compilation_parallelism (unknown flag), so
  # each candidate is tried on a one-line program first and only the ones XLA accepts are kept.
  local par="" f
  for f in ${FLAGS:---xla_gpu_autotune_level=0 --xla_gpu_force_compilation_parallelism=16}; do
    if XLA_FLAGS="$f" python3 -c "import jax.numpy as n; n.ones(2).block_until_ready()" > /dev/null 2>&1; then
      par="$par $f"
    else
      stamp "XLA refuses $f: left out"
    fi
  done
  FLAGS="${par# }"
  rm -rf "$WORK/jaxcache_base" "$WORK/jaxcache_flags"
  # No autotune seed in either: the comparison is XLA's own autotuning against none.
  ppo "cold_base" 200 --compile-cache-dir "$WORK/jaxcache_base" --max-minutes "${COLD_MIN:-1.8}" --no-autotune-seed
  finish flags "$RUNS/cold_base" > /dev/null
  XLA_FLAGS="$FLAGS" ppo "cold_flags" 200 --compile-cache-dir "$WORK/jaxcache_flags" --max-minutes "${COLD_MIN:-1.8}" \
    --no-autotune-seed
  echo "XLA_FLAGS=$FLAGS (cold_flags; cold_base: none)" > "$WORK/flags.md"
  finish flags "$RUNS/cold_base" "$RUNS/cold_flags" --append "$WORK/flags.md" > /dev/null
  [ -n "${NO_PROFILE:-}" ] && return
  stamp "rsl-rl profile"
  local pr=""
  [ -n "$SMOKE" ] && pr="--preset tiny --iters 1"
  JAX_COMPILATION_CACHE_DIR=$WORK/jaxcache_base timeout -k 10 $((190 * TS)) python3 bench/rsl_rl_profile.py $pr \
    --out "$WORK/rsl_profile.md" > "$WORK/rsl_profile.log" 2>&1
  stamp "rsl-rl profile exit $?"
  finish flags "$RUNS/cold_base" "$RUNS/cold_flags" --append "$WORK/flags.md" "$WORK/rsl_profile.md"
}

loadflags() {
  local par="" f
  for f in ${LOAD_FLAGS:---xla_gpu_experimental_aot_compiled_thunks=true}; do
    if XLA_FLAGS="$f" python3 -c "import jax.numpy as n; n.ones(2).block_until_ready()" > /dev/null 2>&1; then
      par="$par $f"
    else
      stamp "XLA refuses $f: left out"
    fi
  done
  local runs=("$RUNS/lf_base_cold" "$RUNS/lf_base_warm" "$RUNS/lf_flags_cold" "$RUNS/lf_flags_warm")
  rm -rf "$WORK/jaxcache_lfb" "$WORK/jaxcache_lff"
  ppo lf_base_cold 200 --compile-cache-dir "$WORK/jaxcache_lfb" --max-minutes "${COLD_MIN:-1.3}"
  ppo lf_base_warm 120 --compile-cache-dir "$WORK/jaxcache_lfb" --max-minutes "${WARM_MIN:-0.8}"
  finish loadflags "${runs[@]}" > /dev/null
  XLA_FLAGS="${par# }" ppo lf_flags_cold 200 --compile-cache-dir "$WORK/jaxcache_lff" --max-minutes "${COLD_MIN:-1.3}"
  XLA_FLAGS="${par# }" ppo lf_flags_warm 120 --compile-cache-dir "$WORK/jaxcache_lff" --max-minutes "${WARM_MIN:-0.8}"
  echo "XLA_FLAGS=${par# } (lf_flags_*; lf_base_*: none)" > "$WORK/loadflags.md"
  finish loadflags "${runs[@]}" --append "$WORK/loadflags.md"
}

update() {
  local conc=--xla_gpu_command_buffer_scheduling_mode=CONCURRENT pr="" label args flags
  [ -n "$SMOKE" ] && pr="--preset tiny --iters 2"
  echo "| run | devices | ms per update | us per Adam step | compile s | settings |" > "$OUT/summary_update.md"
  echo "|---|---|---:|---:|---:|---|" >> "$OUT/summary_update.md"
  stamp "update: per-leaf Adam, profiled"
  # shellcheck disable=SC2086
  XLA_FLAGS=$conc timeout -k 10 $((120 * TS)) python3 bench/update_scaling.py $pr --label "per-leaf Adam" \
    --out "$OUT/summary_update.md" --profile "$WORK/update_trace" --profile-ops 40 > "$OUT/update_profile.md" 2>&1
  stamp "  exit $?"
  # label|arguments|extra XLA flags, separated by ';'
  local variants=${UPDATE_VARIANTS:-"flat Adam|--flat-adam|;cuBLAS matmuls||--xla_gpu_enable_triton_gemm=false"}
  while IFS='|' read -r label args flags; do
    [ -n "$label" ] || continue
    stamp "update: $label"
    # shellcheck disable=SC2086
    XLA_FLAGS="$conc $flags" timeout -k 10 $((120 * TS)) python3 bench/update_scaling.py $pr $args \
      --label "$label" --out "$OUT/summary_update.md" > "$WORK/update_$label.log" 2>&1
    stamp "  exit $?"
  done < <(tr ';' '\n' <<< "$variants")
  rm -rf "$WORK/update_trace"
  cat "$OUT/summary_update.md"
}

precision() {
  local pr=${UPDATE_PRECISION:-tensorfloat32} r runs=()
  COMMON=${COMMON/--no-export-onnx/}
  rm -rf "$CACHE"
  ppo base_s0 200 --compile-cache-dir "$CACHE" --seed 0 --ppo.update-precision run --max-minutes "${COLD_MIN:-1.4}"
  for r in 0 1 2; do
    ppo "prec_s$r" 150 --compile-cache-dir "$CACHE" --seed "$r" --ppo.update-precision "$pr" --max-minutes "${WARM_MIN:-1.1}"
  done
  ppo base_s1 150 --compile-cache-dir "$CACHE" --seed 1 --ppo.update-precision run --max-minutes "${WARM_MIN:-1.1}"
  for r in base_s0 prec_s0 prec_s1 prec_s2 base_s1; do
    runs+=("$RUNS/$r")
    cp "$RUNS/$r/policy.onnx" "$OUT/$r.onnx" 2>/dev/null || stamp "$r: no policy.onnx"
  done
  echo "prec_*: --ppo.update-precision $pr; base_*: --ppo.update-precision run (float32)" > "$WORK/precision.md"
  finish precision "${runs[@]}" --append "$WORK/precision.md"
}

prealloc() {
  local runs=("$RUNS/pa_cold" "$RUNS/pb_cold" "$RUNS/pa_warm" "$RUNS/pb_warm") arm arms=(pa pb) phase
  [ "${PREALLOC_FIRST:-true}" = false ] && arms=(pb pa)
  rm -rf "$WORK/jaxcache_pa" "$WORK/jaxcache_pb"
  for phase in cold warm; do
    for arm in "${arms[@]}"; do
      local value=false minutes=${WARM_MIN:-0.6} limit=120
      [ "$arm" = pa ] && value=true
      [ "$phase" = cold ] && minutes=${COLD_MIN:-1.3} && limit=200
      XLA_PYTHON_CLIENT_PREALLOCATE=$value ppo "${arm}_$phase" $limit --compile-cache-dir "$WORK/jaxcache_$arm" \
        --max-minutes "$minutes"
    done
    [ "$phase" = cold ] && finish prealloc "${runs[@]}" > /dev/null
  done
  echo "pa_*: XLA_PYTHON_CLIENT_PREALLOCATE=true (jax preallocates); pb_*: false (the trainer's default); order: ${arms[*]}" \
    > "$WORK/prealloc.md"
  finish prealloc "${runs[@]}" --append "$WORK/prealloc.md"
}

seeds() {
  local p name
  name=$(python3 -c "import re, jax, jaxlib
k = re.sub('[^a-z0-9]+', '-', jax.local_devices()[0].device_kind.lower().replace('nvidia', '')).strip('-')
print(f'{k}-jaxlib-{jaxlib.__version__}')")
  for p in ${SEED_PRESETS:-rsl track}; do
    rm -rf "$WORK/seedcache_$p"
    ppo "seed_$p" 240 --preset "$p" --compile-cache-dir "$WORK/seedcache_$p" --no-autotune-seed \
      --max-minutes "${SEED_MIN:-2.5}"
    local plist=(reset rollout update init evaluate)
    [ "$p" = rsl ] && plist=("train step" "eval step")
    python3 bench/autotune_seed.py --from "$WORK/seedcache_$p" --name "$name-$p" --out "$OUT" \
      --programs "${plist[@]}" --made-with "python3 train/ppo.py --preset $p, empty compile cache, --no-autotune-seed"
    stamp "seed $p exit $?"
  done
  finish seeds "$RUNS"/seed_* > /dev/null
}

finish() {  # finish PART RUN_DIRS... [--append FILES...]
  local part=$1; shift
  tar -czf "$OUT/h100_$part.tgz" -C "$WORK" --exclude='*.msgpack' --exclude='tb' --exclude='jaxcache*' --exclude='seedcache*' . 2>/dev/null
  stamp "part $part done"
  python3 bench/session_summary.py "$@" --out "$OUT/summary_$part.md"
}

case "$PART" in
  startup) startup ;;
  rsl) rsl ;;
  flags) flags ;;
  loadflags) loadflags ;;
  seeds) seeds ;;
  update | smoke-update) update ;;
  precision) precision ;;
  prealloc) prealloc ;;
  smoke-prealloc) COLD_MIN=8 WARM_MIN=8 prealloc ;;
  smoke-precision) COLD_MIN=8 WARM_MIN=8 precision ;;
  smoke) COLD_MIN=8 WARM_MIN=8 startup; RSL_MIN=0.5 RSL_PRESET=tiny rsl ;;
  smoke-loadflags) COLD_MIN=8 WARM_MIN=8 loadflags ;;
  *) echo "unknown part $PART; parts: startup, rsl, flags, loadflags, seeds, update, precision, prealloc, smoke"; exit 2 ;;
esac
