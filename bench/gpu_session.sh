#!/usr/bin/env bash
# One device call's worth of GPU measurements or training runs, each part under 10 minutes, ending with
# a results table. Run from the repository root after the pip prefix of /work/shared/gpu/README.md:
#
#   bash bench/gpu_session.sh PART [ARGS...]
#
# One GPU (every training run is `python3 train/ppo.py`, the default gpu preset, a wall-clock budget
# --max-minutes from process start, no ONNX export; time to 95 % counts from process start):
#   startup   (~7 min): cold start on an empty compile cache (the shipped autotune seed) -> the same command
#             again (warm: the executable cache) -> raw env throughput at the training batch
#             (bench/mjx_throughput.py, harness c, 4096) -> where an iteration's time goes
#             (bench/train_breakdown.py); COLD_WARM_ONLY=1 stops after the warm run (~4.5 min)
#   rsl       (~8 min): the rsl-rl backend, --max-minutes $RSL_MIN (5), --preset rsl (RSL_PRESET=gpu: brax's
#             values), then bench/rsl_rl_profile.py on the same preset (NO_PROFILE=1: not)
#   flags     (~4 min): two cold starts without the autotune seed, XLA's defaults then XLA_FLAGS=$FLAGS
#             (default: no autotuning, compilation over 16 threads; flags XLA refuses are left out), then
#             bench/rsl_rl_profile.py (NO_PROFILE=1: not)
#   loadflags (~6 min): a cold and a warm run on XLA's defaults, then with XLA_FLAGS=$LOAD_FLAGS, each pair on
#             its own empty cache (jaxlib 0.11.2 refuses the default flag: pass LOAD_FLAGS there)
#   seeds     (~3.5 min a preset): per preset in $SEED_PRESETS (default "rsl track"), a cold run on its own
#             empty cache without the shipped seed, then bench/autotune_seed.py packs its autotune results
#             into $OUT (copy the .tar.gz and .json to bar_policy/data/autotune/)
#   update    (~3 min): bench/update_scaling.py: per-leaf Adam with a kernel profile, then each variant of
#             $UPDATE_VARIANTS ("label|arguments|XLA flags;..."; default flat Adam, cuBLAS matmuls)
#   precision (~7 min): float32 SGD passes against --ppo.update-precision $UPDATE_PRECISION (tensorfloat32):
#             base_s0 (cold), prec_s0..2, base_s1 on one cache, ONNX files to $OUT for the ship gate
#   prealloc  (~5 min): XLA_PYTHON_CLIENT_PREALLOCATE=true against false (the trainer's default), cold then
#             warm, alternated (PREALLOC_FIRST=false runs false first), each arm on its own empty cache
#
# Several GPUs of one host (NCCL without NVLink multicast):
#   scaling N (~6-8 min): the gpu preset at the same per-device size (4096 envs, batch 256 per GPU; BATCH=512
#             for the figures before 2026-11-27) on N GPUs: gN_cold on an empty cache, gN_warm (NO_WARM=1:
#             not), g1 on GPU 0 (its own cache: the baseline of the ratio), and for N >= 4 g2 on GPUs 0,1;
#             DIST=1 adds 2 processes on GPUs 0,1 through jax.distributed (dist2). Budgets COLD_MIN (1.8),
#             WARM_MIN (1.2), G1_MIN (1.6)
#
# Training recipes (named variants of a task's preset, one per GPU of $GPUS, e.g. GPUS="0 1 2 3"; without
# GPUS they share the one GPU; SEED=S sets every run's seed and names it <variant>-seed<S>, VARIANT@S one
# run's, e.g. `recipe piano stiff@0 stiff@1 stiff@2`):
#   recipe reach VARIANT... (~3 min): each a cold run on its own cache, every 327,680 env steps evaluated with
#             EXTRA="--eval.num-evals 124"; BASE="..." goes before each variant's flags; ONNX=1 exports;
#             MINUTES (2.2). Judged by the env steps to 95 % and the steady env steps/s
#   recipe track VARIANT... (~9.5 min): --preset track on one shared cache, MINUTES (8.9); A and B name the
#             ablation sets; `SEED=0 ... recipe track recipe` is the figure of record; rsl: the field's
#             rsl-rl values (field_cli_flags(8192)) on the preset's networks and prior, initial std 0.3;
#             rsl-fixed: --preset track-rsl; ema, integral: the error average's layout without and with
#             the prior's integral term (integral_warm: 10 critic-only iterations first, as the piano's);
#             robust_integral: track-robust from scratch with it (robust_integral_quiet: initial std 0.1
#             and 10 critic-only iterations, the piano's start); integral_quiet[_lr1e-4|_lr3e-5] and
#             robust_integral_quiet_lr3e-5: that start at the preset's or a lower learning rate;
#             [robust_]integral_std03: initial std 0.03 (docs/robust_training.md). Without GPUS the
#             variants share the GPU at 4096 envs, batch 512 (XLA_PYTHON_CLIENT_MEM_FRACTION=$MEM, 0.22);
#             NO_CKPT=1 leaves the checkpoints out
#   recipe piano VARIANT... (~9 min): --preset piano, MINUTES (7.2); robust, robust_hover36: piano-robust,
#             with the 36 mm hover (docs/robust_training.md); [robust_]std03: initial std 0.03;
#             robust_std03_off2: that with the piano preset's +-2 mrad encoder offsets; robust_fs025_off2: the
#             preset's std with each robust factor on in a quarter of the slots or episodes; lead3,
#             robust_fs025_off2_lead3: the song read 3 steps ahead (the preset's 2); robust_fs025_off2_ff:
#             robust_fs025_off2 with 0.5-1.0 of the payload's gravity torque sent as tau_ff (the runtime's
#             hand-load compensation); robust_fs025_off2_ff_lead3: that at lead 3; robust_fs025_off2_ff_dev2:
#             with reward.scales.prior_deviation_black -2 (the residual's cost at black goals); _dev8: -8;
#             robust_fs025_off2_ff_dev2_lead3: _dev2 at lead 3; _dev8_rest8, _dev8_rest32, _dev8_rest8_lead3:
#             _dev8 with reward.scales.prior_deviation_rest -8 or -32 (the residual's cost in the count-in);
#             stiff, stiff_lead3, stiff_std03: the stiff gain profile (Kp 100, Kd 3; robot.gains)
#
# smoke-PART (smoke-startup, smoke-rsl, smoke-update, smoke-precision, smoke-prealloc, smoke-loadflags,
# smoke-scaling N, smoke-recipe TASK): the part's logic on the CPU with tiny sizes.
# TRAIN_ARGS / EXTRA: more arguments for every training run; EXPORT_ONNX=1 keeps the export (one-GPU parts).
# Work goes to $WORK; $OUT gets summary_<part>.md (the table printed last) and session_<part>.tgz (logs,
# metrics, configs; the recipes: each run's files, the track runs' newest checkpoint).
set -u
# A device's copy of the checkout may carry a stale .git, whose answer would win over BAR_POLICY_GIT_COMMIT:
# with the commit stated, git is kept out (docs/training.md, "Provenance").
if [ -n "${BAR_POLICY_GIT_COMMIT:-}" ]; then export GIT_DIR=/nonexistent; fi
PART=${1:-}
[ $# -gt 0 ] && shift
SMOKE=""
TS=1  # timeout scale: a CPU compiles the same programs several times slower
if [ "${PART#smoke-}" != "$PART" ]; then
  PART=${PART#smoke-}
  SMOKE=1
  TS=6
  export JAX_PLATFORMS=cpu
fi
OUT=${OUT:-/tmp/gpu_session_out}
WORK=${WORK:-/tmp/gpu_session}
RUNS=$WORK/runs
CACHE=$WORK/jaxcache
mkdir -p "$OUT" "$WORK"
export PYTHONUNBUFFERED=1 NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
T0=$(date +%s)
# Bytecode for what is on PYTHONPATH: a pip install writes it, the lent machine's --no-compile prefix does
# not (the warm run's imports 3.4 -> 2.4 s on an H100 machine, 2026-11-27).
[ -z "${PYTHONPATH:-}" ] || python3 -m compileall -q -j 0 ${PYTHONPATH//:/ } > /dev/null 2>&1 || true
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }

TINY="--preset tiny --ppo.num-timesteps 2048 --final-eval-envs 16"
NO_EXPORT=--no-export-onnx
[ -n "${EXPORT_ONNX:-}" ] && NO_EXPORT=""
COMMON="--runs-dir $RUNS $NO_EXPORT --final-eval-envs 1024 ${SMOKE:+$TINY} ${TRAIN_ARGS:-}"

ppo() {  # ppo NAME TIMEOUT_S ARGS...: one training run on what the process sees; its start-up lines
  local name=$1 t=$2; shift 2
  stamp "train $name: $*"
  # shellcheck disable=SC2086
  timeout -k 10 $((t * TS)) python3 train/ppo.py --run-name "$name" $COMMON "$@" > "$WORK/$name.log" 2>&1
  stamp "train $name exit $?"
  grep -v "^WARNING\|^I0000\|^W0000" "$WORK/$name.log" | grep -A16 "^start-up" | head -n 18
}

finish() {  # finish PART RUN_DIRS... [--append FILES...]: the archive, then the table (after every step)
  local part=$1; shift
  tar -czf "$OUT/session_$part.tgz" -C "$WORK" --exclude='*.msgpack' --exclude='tb' --exclude='jaxcache*' \
    --exclude='seedcache*' --exclude='cache*' . 2>/dev/null
  stamp "part $part done"
  python3 bench/session_summary.py "$@" --out "$OUT/summary_$part.md"
}

accepted_flags() {  # accepted_flags FLAGS...: those XLA accepts on a one-line program
  local par="" f
  for f in "$@"; do
    if XLA_FLAGS="$f" python3 -c "import jax.numpy as n; n.ones(2).block_until_ready()" > /dev/null 2>&1; then
      par="$par $f"
    else
      stamp "XLA refuses $f: left out" >&2
    fi
  done
  echo "${par# }"
}

# -- one GPU -----------------------------------------------------------------------------------------
startup() {
  [ -n "$SMOKE" ] && COLD_MIN=${COLD_MIN:-8} WARM_MIN=${WARM_MIN:-8}
  rm -rf "$CACHE"
  local runs=("$RUNS/cold" "$RUNS/warm") app=(--append "$WORK/raw_env.md" "$WORK/breakdown.md")
  ppo cold 230 --compile-cache-dir "$CACHE" --max-minutes "${COLD_MIN:-2.6}"
  finish startup "${runs[@]}" "${app[@]}" > /dev/null  # a killed call still returns the table so far
  ppo warm 120 --compile-cache-dir "$CACHE" --max-minutes "${WARM_MIN:-1.4}"
  finish startup "${runs[@]}" "${app[@]}" > /dev/null
  if [ -n "${COLD_WARM_ONLY:-}" ]; then finish startup "${runs[@]}"; return; fi
  stamp "raw env throughput (harness c, training batch)"
  local b=4096 extra="" bd=""
  [ -n "$SMOKE" ] && b=16 && extra="--min-time 1 --min-iters 2" && bd="--preset tiny --iters 1"
  # shellcheck disable=SC2086
  timeout -k 10 $((100 * TS)) python3 bench/mjx_throughput.py --harness c --batches $b --no-diagnose $extra \
    --out "$WORK/raw_env.md" > "$WORK/raw_env.log" 2>&1
  stamp "raw env exit $?"
  finish startup "${runs[@]}" "${app[@]}" > /dev/null
  stamp "train breakdown"
  # shellcheck disable=SC2086
  JAX_COMPILATION_CACHE_DIR=$CACHE timeout -k 10 $((120 * TS)) python3 bench/train_breakdown.py $bd \
    --out "$WORK/breakdown.md" > "$WORK/breakdown.log" 2>&1
  stamp "breakdown exit $?"
  tail -n 3 "$WORK/breakdown.log"
  finish startup "${runs[@]}" "${app[@]}"
}

rsl_profile() {  # rsl_profile CACHE TIMEOUT_S PRESET_ARGS...: bench/rsl_rl_profile.py to $WORK/rsl_profile.md
  local cache=$1 t=$2; shift 2
  stamp "rsl-rl profile"
  local pr=("$@")
  [ -n "$SMOKE" ] && pr=(--preset tiny --iters 1)
  JAX_COMPILATION_CACHE_DIR=$cache timeout -k 10 $((t * TS)) python3 bench/rsl_rl_profile.py "${pr[@]}" \
    --out "$WORK/rsl_profile.md" > "$WORK/rsl_profile.log" 2>&1
  stamp "rsl-rl profile exit $?"
}

rsl() {
  local preset=${RSL_PRESET:-rsl}
  [ -n "$SMOKE" ] && preset=tiny
  ppo rsl 450 --compile-cache-dir "$CACHE" --preset "$preset" --backend rsl-rl --max-minutes "${RSL_MIN:-5}"
  grep -v "^WARNING" "$WORK/rsl.log" | grep "steps/s" | tail -n 3
  finish rsl "$RUNS/rsl" > /dev/null
  [ -n "${NO_PROFILE:-}" ] && { finish rsl "$RUNS/rsl"; return; }
  rsl_profile "$CACHE" 150 --preset "$preset"
  finish rsl "$RUNS/rsl" --append "$WORK/rsl_profile.md"
}

flags() {
  FLAGS=$(accepted_flags ${FLAGS:---xla_gpu_autotune_level=0 --xla_gpu_force_compilation_parallelism=16})
  rm -rf "$WORK/jaxcache_base" "$WORK/jaxcache_flags"
  # No autotune seed in either: the comparison is XLA's own autotuning against none.
  ppo cold_base 200 --compile-cache-dir "$WORK/jaxcache_base" --max-minutes "${COLD_MIN:-1.8}" --no-autotune-seed
  finish flags "$RUNS/cold_base" > /dev/null
  XLA_FLAGS="$FLAGS" ppo cold_flags 200 --compile-cache-dir "$WORK/jaxcache_flags" \
    --max-minutes "${COLD_MIN:-1.8}" --no-autotune-seed
  echo "XLA_FLAGS=$FLAGS (cold_flags; cold_base: none)" > "$WORK/flags.md"
  finish flags "$RUNS/cold_base" "$RUNS/cold_flags" --append "$WORK/flags.md" > /dev/null
  [ -n "${NO_PROFILE:-}" ] && return
  rsl_profile "$WORK/jaxcache_base" 190
  finish flags "$RUNS/cold_base" "$RUNS/cold_flags" --append "$WORK/flags.md" "$WORK/rsl_profile.md"
}

loadflags() {
  [ -n "$SMOKE" ] && COLD_MIN=${COLD_MIN:-8} WARM_MIN=${WARM_MIN:-8}
  local par
  par=$(accepted_flags ${LOAD_FLAGS:---xla_gpu_experimental_aot_compiled_thunks=true})
  local runs=("$RUNS/lf_base_cold" "$RUNS/lf_base_warm" "$RUNS/lf_flags_cold" "$RUNS/lf_flags_warm")
  rm -rf "$WORK/jaxcache_lfb" "$WORK/jaxcache_lff"
  ppo lf_base_cold 200 --compile-cache-dir "$WORK/jaxcache_lfb" --max-minutes "${COLD_MIN:-1.3}"
  ppo lf_base_warm 120 --compile-cache-dir "$WORK/jaxcache_lfb" --max-minutes "${WARM_MIN:-0.8}"
  finish loadflags "${runs[@]}" > /dev/null
  XLA_FLAGS="$par" ppo lf_flags_cold 200 --compile-cache-dir "$WORK/jaxcache_lff" --max-minutes "${COLD_MIN:-1.3}"
  XLA_FLAGS="$par" ppo lf_flags_warm 120 --compile-cache-dir "$WORK/jaxcache_lff" --max-minutes "${WARM_MIN:-0.8}"
  echo "XLA_FLAGS=$par (lf_flags_*; lf_base_*: none)" > "$WORK/loadflags.md"
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
  [ -n "$SMOKE" ] && COLD_MIN=${COLD_MIN:-8} WARM_MIN=${WARM_MIN:-8}
  local pr=${UPDATE_PRECISION:-tensorfloat32} r runs=()
  COMMON=${COMMON/--no-export-onnx/}
  rm -rf "$CACHE"
  ppo base_s0 200 --compile-cache-dir "$CACHE" --seed 0 --ppo.update-precision run --max-minutes "${COLD_MIN:-1.4}"
  for r in 0 1 2; do
    ppo "prec_s$r" 150 --compile-cache-dir "$CACHE" --seed "$r" --ppo.update-precision "$pr" \
      --max-minutes "${WARM_MIN:-1.1}"
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
  [ -n "$SMOKE" ] && COLD_MIN=${COLD_MIN:-8} WARM_MIN=${WARM_MIN:-8}
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
  echo "pa_*: XLA_PYTHON_CLIENT_PREALLOCATE=true; pb_*: false (the trainer's default); order: ${arms[*]}" \
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

# -- several GPUs ------------------------------------------------------------------------------------
devices() {  # devices LIST N: the GPUs a run sees (smoke: N forced CPU devices)
  if [ -n "$SMOKE" ]; then echo "XLA_FLAGS=--xla_force_host_platform_device_count=$2"; else echo "CUDA_VISIBLE_DEVICES=$1"; fi
}

per_device() {  # per_device NAME GPU_LIST N CACHE MINUTES TIMEOUT_S [ARGS...]: the gpu preset's size per device
  local name=$1 list=$2 n=$3 cache=$4 minutes=$5 t=$6; shift 6
  local envs=4096 batch=${BATCH:-256} final=1024 sizes=""
  [ -n "$SMOKE" ] && envs=16 && batch=16 && final=16 && sizes="--preset tiny --ppo.num-timesteps 2048"
  stamp "train $name on $n device(s) ($list), cache $cache, --max-minutes $minutes"
  # shellcheck disable=SC2046,SC2086
  env $(devices "$list" "$n") timeout -k 10 $((t * TS)) python3 train/ppo.py --run-name "$name" \
    --runs-dir "$RUNS" --no-export-onnx --final-eval-envs $final --compile-cache-dir "$cache" \
    --max-minutes "$minutes" $sizes --ppo.num-envs $((envs * n)) --ppo.batch-size $((batch * n)) \
    ${TRAIN_ARGS:-} "$@" > "$WORK/${LOG:-$name}.log" 2>&1
  stamp "train $name exit $?"
  grep -v "^WARNING\|^I0000\|^W0000" "$WORK/${LOG:-$name}.log" | grep -A14 "^start-up" | head -n 16
}

dist2() {  # two processes (jax.distributed on localhost) on GPUs 0,1, one device each
  local port=$((20000 + RANDOM % 20000)) pid
  local d=(--distributed.coordinator-address "127.0.0.1:$port" --distributed.num-processes 2)
  for pid in 0 1; do
    local ids=(--distributed.local-device-ids "$pid")
    [ -n "$SMOKE" ] && ids=()
    LOG=dist2_p$pid per_device dist2 0,1 2 "$WORK/cache_dist" "${G1_MIN:-1.6}" 170 "${d[@]}" \
      --distributed.process-id "$pid" "${ids[@]}" &
  done
  wait
}

scaling() {  # scaling N
  local n=${1:-2} list
  list=$(seq -s, 0 $((n - 1)))
  local runs=("$RUNS/g1" "$RUNS/g${n}_cold" "$RUNS/g${n}_warm")
  rm -rf "$WORK"/cache_*
  per_device "g${n}_cold" "$list" "$n" "$WORK/cache_g$n" "${COLD_MIN:-1.8}" 170
  finish scaling "${runs[@]}" > /dev/null
  if [ -z "${NO_WARM:-}" ]; then
    per_device "g${n}_warm" "$list" "$n" "$WORK/cache_g$n" "${WARM_MIN:-1.2}" 120
    finish scaling "${runs[@]}" > /dev/null
  fi
  per_device g1 0 1 "$WORK/cache_g1" "${G1_MIN:-1.6}" 150
  if [ "$n" -ge 4 ]; then
    runs+=("$RUNS/g2")
    per_device g2 0,1 2 "$WORK/cache_g2" "${G1_MIN:-1.6}" 150
  fi
  if [ -n "${DIST:-}" ]; then
    runs+=("$RUNS/dist2")
    dist2
  fi
  finish scaling "${runs[@]}"
}

# -- training recipes --------------------------------------------------------------------------------
declare -A VARIANT
recipe_variants() {  # recipe_variants TASK: VARIANT (name -> extra arguments on top of the task's preset)
  case "$1" in
    reach)
      VARIANT=(
        [base]="" [envs8192]="--ppo.num-envs 8192 --ppo.batch-size 1024" [lr1e-3]="--ppo.learning-rate 1e-3"
        [upd4]="--ppo.num-updates-per-batch 4" [upd16]="--ppo.num-updates-per-batch 16"
        [mb8]="--ppo.num-minibatches 8 --ppo.batch-size 1024" [unroll20]="--ppo.unroll-length 20"
        [unroll5]="--ppo.unroll-length 5" [ent1e-3]="--ppo.entropy-cost 1e-3" [bs256]="--ppo.batch-size 256"
        [bs512]="--ppo.batch-size 512" [dt2]="--env-overrides sim_dt=0.002"
        [adaptive]="--ppo.schedule adaptive --ppo.learning-rate 1e-3"
        [wp0]="--env-overrides reward.scales.wrist_posture=0" [eps0]="--ppo.obs-std-eps 0"
        [vt]="--ppo.value-targets iteration" [pass]="--ppo.value-targets pass"
      ) ;;
    track)
      local old="reward.scales.action_rate=-0.005 reward.scales.torque_near_cap=0.0 reward.scales.fingertip_pos=0.0"
      old="$old action_filter_hz=null sampling.enabled=false"
      local ema="--env-overrides joint_error_ema=true"  # the error average's layout
      # the integral prior with the piano's start (10 critic-only iterations)
      local warm="--network.prior-error-gain 1 --ppo.actor-warmup-iterations 10"
      VARIANT=(
        [recipe]="" [actuator_gains]="--env-overrides gains=actuator"
        [no_filter]="--env-overrides action_filter_hz=null"
        [weak_action_rate]="--env-overrides reward.scales.action_rate=-0.005"
        [old]="--ppo.schedule fixed --matmul-precision default --network.action-prior none --env-overrides $old"
        [no_sampling]="--env-overrides sampling.enabled=false" [fixed_lr]="--ppo.schedule fixed"
        [no_near_cap]="--env-overrides reward.scales.torque_near_cap=0.0" [tf32]="--matmul-precision default"
        [rsl]="RSL" [rsl-fixed]="--preset track-rsl"  # the last --preset wins
        [ema]="$ema"  # no integral: the control
        [integral]="$ema --network.prior-error-gain 1"
        [integral_warm]="$ema $warm"
        [robust_integral]="--preset track-robust --network.prior-error-gain 1"  # from scratch, randomised
        [robust_integral_quiet]="--preset track-robust $warm --network.prior-noise-std 0.1"
        [integral_quiet]="$ema $warm --network.prior-noise-std 0.1"  # the preset's 3e-4
        [integral_quiet_lr1e-4]="$ema $warm --network.prior-noise-std 0.1 --ppo.learning-rate 1e-4"
        [integral_quiet_lr3e-5]="$ema $warm --network.prior-noise-std 0.1 --ppo.learning-rate 3e-5"
        [robust_integral_quiet_lr3e-5]="--preset track-robust $warm --network.prior-noise-std 0.1 --ppo.learning-rate 3e-5"
        [integral_std03]="$ema $warm --network.prior-noise-std 0.03"  # rollouts inside the fingertip kernel
        [robust_integral_std03]="--preset track-robust $warm --network.prior-noise-std 0.03"
      ) ;;
    piano)
      # each robust factor on in a quarter of the slots or episodes, the +-2 mrad offsets: on every factor at once the
      # prior reads F1 0.53 (0.79 at this share), and its residual trades the nominal robot's black keys for it
      local fs025="--preset piano-robust --env-overrides randomization.factor_share=0.25 actuator.encoder_offset=0.002"
      local ff="$fs025 randomization.payload_ff_share=0.5,1.0"
      local d8="$ff reward.scales.prior_deviation_black=-8.0"
      VARIANT=(
        [preset]="" [accel]="--env-overrides reward.scales.action_accel=-0.5 reward.scales.torque_near_cap=-1.0"
        [lr3e-4]="--ppo.learning-rate 3e-4"
        [robust]="--preset piano-robust" [robust_hover36]="--preset piano-robust --env-overrides prior.hover_m=0.036"
        [std03]="--network.prior-noise-std 0.03" [robust_std03]="--preset piano-robust --network.prior-noise-std 0.03"
        # the piano's own +-2 mrad offsets kept (the robust items widen them to 10 mrad, where the prior alone falls to F1 0.810)
        [robust_std03_off2]="--preset piano-robust --network.prior-noise-std 0.03 --env-overrides actuator.encoder_offset=0.002"
        [robust_fs025_off2]="$fs025"
        # the song read 3 steps (60 ms) ahead: the shipped file played so passes the delay row (docs/robust_training.md)
        [lead3]="--env-overrides playback.lead_steps=3" [robust_fs025_off2_lead3]="$fs025 playback.lead_steps=3"
        # the runtime's hand-load compensation modelled: a share of the payload's gravity torque sent as tau_ff
        [robust_fs025_off2_ff]="$ff" [robust_fs025_off2_ff_lead3]="$ff playback.lead_steps=3"
        # a cost on the residual at black goals (the trained residuals lose the prior's black presses)
        [robust_fs025_off2_ff_dev2]="$ff reward.scales.prior_deviation_black=-2.0"
        [robust_fs025_off2_ff_dev8]="$d8"
        [robust_fs025_off2_ff_dev2_lead3]="$ff reward.scales.prior_deviation_black=-2.0 playback.lead_steps=3"
        # and a cost on it in the count-in, where the tare fits (a residual moving the arm there reads friction as load)
        [robust_fs025_off2_ff_dev8_rest8]="$d8 reward.scales.prior_deviation_rest=-8.0"
        [robust_fs025_off2_ff_dev8_rest32]="$d8 reward.scales.prior_deviation_rest=-32.0"
        [robust_fs025_off2_ff_dev8_rest8_lead3]="$d8 reward.scales.prior_deviation_rest=-8.0 playback.lead_steps=3"
        # the stiff gain profile (Kp 100, Kd 3: robot.gains): the prior alone presses faster against friction
        [stiff]="--env-overrides gains=stiff" [stiff_lead3]="--env-overrides gains=stiff playback.lead_steps=3"
        [stiff_std03]="--env-overrides gains=stiff --network.prior-noise-std 0.03"
      ) ;;
    *) echo "unknown task ${1:-} for recipe; tasks: reach, track, piano"; exit 2 ;;
  esac
}

rsl_field_args() {  # the field's rsl-rl values on the track preset's networks, prior and initial std 0.3
  local flags
  flags=$(python3 -c "
from bar_policy.training.rsl_rl.config import field_cli_flags
own = ('network.policy_hidden', 'network.value_hidden', 'network.init_noise_std', 'ppo.update_precision')
print(' '.join(field_cli_flags(8192, leave_out=own)))") || exit 1
  echo "--backend rsl-rl $flags --network.init-noise-std 0.3"
}

recipe() {  # recipe TASK VARIANT...
  local task=${1:-}; shift || true
  recipe_variants "$task"
  local names=("$@") v
  [ "$task" = track ] && [ "${names[*]}" = A ] && names=(recipe actuator_gains no_filter weak_action_rate)
  [ "$task" = track ] && [ "${names[*]}" = B ] && names=(no_sampling fixed_lr no_near_cap tf32)
  [ -n "$SMOKE" ] && [ ${#names[@]} -eq 0 ] && names=("${!VARIANT[@]}") && names=("${names[0]}")
  [ ${#names[@]} -gt 0 ] || { echo "recipe $task: name variants (${!VARIANT[*]})"; exit 2; }
  for v in "${names[@]}"; do
    [ -n "${VARIANT[${v%@*}]+x}" ] || { echo "unknown variant ${v%@*} for $task; valid: ${!VARIANT[*]}"; exit 2; }
  done
  local preset minutes t args=() gpus
  case "$task" in
    reach) preset=gpu; minutes=${MINUTES:-2.2}; t=240; args=(--final-eval-envs 1024 ${BASE:-})
           [ "${ONNX:-0}" = 1 ] || args+=(--no-export-onnx) ;;
    track) preset=track; minutes=${MINUTES:-8.9}; t=585; args=(--final-eval-envs 1024 --compile-cache-dir "$CACHE") ;;
    piano) preset=piano; minutes=${MINUTES:-7.2}; t=575; args=(--final-eval-envs 512) ;;
  esac
  read -r -a gpus <<< "${GPUS:-}"
  if [ ${#gpus[@]} -eq 0 ] && [ ${#names[@]} -gt 1 ]; then  # side by side on the one GPU
    export XLA_PYTHON_CLIENT_MEM_FRACTION=${MEM:-0.22}
    [ "$task" = track ] && args+=(--ppo.num-envs 4096 --ppo.batch-size 512)
  fi
  if [ -n "$SMOKE" ]; then
    minutes=0
    args+=(--ppo.num-envs 16 --ppo.batch-size 16 --ppo.num-minibatches 2 --ppo.unroll-length 4
      --ppo.num-updates-per-batch 1 --ppo.num-timesteps 256 --eval.num-eval-envs 8 --eval.num-evals 2
      --final-eval-envs 8 --network.policy-hidden 16 16 --network.value-hidden 16 16)
  fi
  rm -rf "$WORK"/cache_* "$RUNS"  # a rerun starts afresh (a used run name is refused)
  local i=0 runs=() name extra seed
  for v in "${names[@]}"; do
    seed=${SEED:-}
    [ "$v" != "${v%@*}" ] && seed=${v#*@}  # VARIANT@S: this run's seed
    v=${v%@*}
    name=$v${seed:+-seed$seed}
    runs+=("$RUNS/$name")
    extra=${VARIANT[$v]}
    [ "$extra" = RSL ] && extra=$(rsl_field_args)
    local own=()
    [ "$task" = reach ] && own=(--compile-cache-dir "$WORK/cache_$name")
    stamp "start $name (GPU ${gpus[$i]:-shared}): $extra"
    # shellcheck disable=SC2046,SC2086
    env $([ -n "${gpus[$i]:-}" ] && echo "CUDA_VISIBLE_DEVICES=${gpus[$i]}") timeout -k 5 $((${RUN_TIMEOUT:-$t} * TS)) \
      python3 train/ppo.py --preset "$preset" ${seed:+--seed $seed} --run-name "$name" --runs-dir "$RUNS" \
      --max-minutes "$minutes" "${own[@]}" $extra "${args[@]}" ${EXTRA:-} > "$WORK/$name.log" 2>&1 &
    i=$((i + 1))
    sleep 2
  done
  wait
  stamp "runs done"
  for d in "$RUNS"/*/checkpoints; do  # keep each run's newest checkpoint only
    [ -d "$d" ] && ls -1 "$d"/step_*.msgpack 2>/dev/null | head -n -1 | sed 's/.msgpack$//' | \
      while read -r old; do rm -f "$old.msgpack" "$old.json"; done
  done
  local keep=(--exclude='*.msgpack')
  [ "$task" = track ] && [ -z "${NO_CKPT:-}" ] && keep=()
  (cd "$WORK" && tar czf "$OUT/session_recipe_$task.tgz" "${keep[@]}" --exclude=tb --exclude='cache_*' \
    --exclude=jaxcache runs ./*.log 2>/dev/null)
  case "$task" in
    reach) python3 bench/session_summary.py "${runs[@]}" --out "$OUT/summary_recipe_reach.md" ;;
    track) python3 bench/recipe_summary.py "$RUNS" --keys success_rate joint_error_rad fingertip_error_cm \
             quality/completion_pct quality/cap_share_pct quality/chatter_max_mrad quality/chatter_mean_mrad \
             quality/action_rate --best joint_error_rad fingertip_error_cm quality/completion_pct \
             quality/cap_share_pct quality/chatter_max_mrad > "$OUT/summary_recipe_track.md" ;;
    piano) python3 bench/recipe_summary.py "$RUNS" --keys f1 precision recall quality/completion_pct \
             quality/cap_share_pct quality/chatter_max_mrad --best f1 > "$OUT/summary_recipe_piano.md" ;;
  esac
  [ "$task" = reach ] || cat "$OUT/summary_recipe_$task.md"  # session_summary.py prints its own
}

PARTS="startup, rsl, flags, loadflags, seeds, update, precision, prealloc, scaling N, recipe TASK VARIANT..."
case "$PART" in
  startup | rsl | flags | loadflags | seeds | update | precision | prealloc) "$PART" ;;
  scaling) scaling "$@" ;;
  recipe) recipe "$@" ;;
  *) echo "unknown part '$PART'; parts: $PARTS (smoke-<part>: on the CPU, tiny sizes)"; exit 2 ;;
esac
stamp done
