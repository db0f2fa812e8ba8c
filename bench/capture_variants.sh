#!/usr/bin/env bash
# Issue 19's steady-loop target (loop >= 90 % of the raw env) on one GPU: does a physics step that XLA can
# record whole into CUDA graphs change the picture? (docs/performance.md, session 42.)
#
# XLA records no cuSOLVER potrf and no cuBLAS triangular solve into a command buffer, and a while loop
# becomes a graph node only when its whole body can be recorded (and WHILE is among the enabled command
# types, which by default it is not). The reach step's library Cholesky calls therefore split every
# physics step's graphs, and MJX's Newton while_loop sends its predicate to the host on every iteration.
# The env option `cholesky=columns` (or `scalar`) builds the step on written-out factors (envs.small_spd),
# which leave no library call in it (tests/envs/test_physics_step.py lowers it for CUDA).
#
# One process per variant, each `bench/train_breakdown.py` (env alone, rollout, update, epoch, loop):
#   VARIANTS (default below): NAME=CHOLESKY:XLA_FLAGS entries, separated by spaces; the flags' commas
#   are kept as they are. Every variant gets the trainer's schedule (CONCURRENT) unless it names one.
#   PIPE=1: then bench/stream_overlap.py --plain (the update of one iteration beside the next rollout in
#   one program) under PIPE_VARIANT (default columns_while). Off unless set (it was on by default until
#   session 46, whose first call spent 100 s on it unasked; sessions 41-44 answered what it asks).
#   DUMP=1: the overlap's process also dumps XLA's optimised HLO of its programs (DUMP_MODULES, a regex
#   of module names; into DUMP_DIR, not $OUT) and bench/command_buffers.py reports what of each runs
#   outside a command buffer ($OUT/command_buffers_<name>.md); XLA's own log of the thunks it leaves out
#   of command buffers (TF_CPP_VMODULE, VLOG 2) is summarised in $OUT/command_buffer_log_overlap_<name>.md.
#   VLOG=1: each breakdown process also logs XLA's command-buffer decisions (TF_CPP_VMODULE, VLOG 2),
#   summarised in $OUT/command_buffer_log_<name>.md and then dropped from its log (session 44's calls 2-3).
#   STEP_TIMEOUT: seconds per process (default 240). BREAKDOWN_ARGS / OVERLAP_ARGS: the two benches' other
#   arguments (defaults below; the overlap's: the gpu preset, 5 timed calls). Each process gets
#   `--env-overrides cholesky=<form>` (added to the preset's own, so the gpu preset keeps its 4 ms step; session
#   43's first call passed `--set env_overrides=...`, which replaced them and measured at 2 ms).
# $OUT gets breakdown_<name>.md per variant, overlap_<name>.md and summary_capture.md (the rows side by side).
#
# Usage (repository root, after the pip prefix of /work/shared/gpu/README.md):
#   bash bench/capture_variants.sh
#   VARIANTS="lib=library: col=columns:" PIPE=1 PIPE_VARIANT=col JAX_PLATFORMS=cpu \
#     BREAKDOWN_ARGS="--preset tiny --iters 1 --epoch-iters 1" \
#     OVERLAP_ARGS="--preset tiny --iters 1 --micro-steps 4" bash bench/capture_variants.sh   # CPU smoke
set -u
OUT=${OUT:-/tmp/capture_out}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
CONC=--xla_gpu_command_buffer_scheduling_mode=CONCURRENT
WHILE=--xla_gpu_enable_command_buffer=+WHILE
VARIANTS=${VARIANTS:-"library=library:$CONC columns=columns:$CONC library_while=library:$CONC $WHILE columns_while=columns:$CONC $WHILE"}
BREAKDOWN_ARGS=${BREAKDOWN_ARGS:-"--iters 2 --epoch-iters 4"}
OVERLAP_ARGS=${OVERLAP_ARGS:-}
STEP_TIMEOUT=${STEP_TIMEOUT:-240}
DUMP_DIR=${DUMP_DIR:-/tmp/capture_dump}
DUMP_MODULES=${DUMP_MODULES:-"jit_(rollout|update|pipelined|interleaved)"}
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
VMODULE="command_buffer_conversion_pass=2,command_buffer_scheduling=2"
XLA_INFO='^[IVW][0-9]{4} '  # the start of an XLA/absl log line

# cb_reasons LOG: XLA's command-buffer log in LOG (VMODULE), as the buffers it made and the thunks it left
# out of one, by its reason (count, message)
cb_reasons() {
  echo "XLA's command-buffer log (TF_CPP_VMODULE=$VMODULE): $(grep -cE "$XLA_INFO" "$1") info lines"
  echo; echo "command buffers created: $(grep -c 'Creating command buffer thunk' "$1")"
  echo; echo "thunks left out of a command buffer, by XLA's reason (count, message):"
  grep -oE "Unsupported thunk kind: [A-Za-z0-9_]+|Thunk kind [A-Za-z0-9_]+ lowering is not enabled[^.]*|Thunk kind [A-Za-z0-9_]+ is not lowered to command buffer[^.]*|[A-Za-z0-9]+Thunk is not convertible[^.]*" \
    "$1" | sort | uniq -c | sort -rn | head -25
}

# "a=x:F1 F2 b=y:F3" -> one line per variant: name, cholesky, flags
split_variants() {
  python3 - "$VARIANTS" <<'EOF'
import re, sys
for m in re.finditer(r"(\w+)=(\w+):(.*?)(?=\s+\w+=\w+:|$)", sys.argv[1].strip()):
    print(m.group(1), m.group(2), m.group(3).strip(), sep="\t")
EOF
}

declare -A FLAGS_OF CHOL_OF
NAMES=()
while IFS=$'\t' read -r name chol flags; do
  NAMES+=("$name"); CHOL_OF[$name]=$chol; FLAGS_OF[$name]=$flags
done < <(split_variants)
[ ${#NAMES[@]} -gt 0 ] || { echo "no variant in VARIANTS=$VARIANTS (NAME=CHOLESKY:FLAGS ...)"; exit 2; }

for name in "${NAMES[@]}"; do
  stamp "breakdown $name: cholesky=${CHOL_OF[$name]}, XLA_FLAGS '${FLAGS_OF[$name]}'"
  vlog=()
  [ "${VLOG:-0}" = 1 ] && vlog=(TF_CPP_MIN_LOG_LEVEL=0 "TF_CPP_VMODULE=$VMODULE")
  log="$OUT/breakdown_$name.log"
  # shellcheck disable=SC2086
  env "${vlog[@]}" XLA_FLAGS="${FLAGS_OF[$name]}" timeout "$STEP_TIMEOUT" python3 bench/train_breakdown.py \
    $BREAKDOWN_ARGS --env-overrides cholesky="${CHOL_OF[$name]}" --out "$OUT/breakdown_$name.md" > "$log" 2>&1
  stamp "  rc $? ($(grep -c . "$log") log lines)"
  if [ "${VLOG:-0}" = 1 ]; then
    cb_reasons "$log" > "$OUT/command_buffer_log_$name.md"
    grep -vE "$XLA_INFO" "$log" > "$log.tmp"; mv "$log.tmp" "$log"
  fi
done

if [ "${PIPE:-0}" = 1 ]; then
  name=${PIPE_VARIANT:-columns_while}
  flags="${FLAGS_OF[$name]:-}" log="$OUT/overlap_$name.log" vlog=()
  if [ "${DUMP:-0}" = 1 ]; then
    # XLA's optimised HLO of the overlap's programs (read by command_buffers.py) and its own account of
    # each thunk it leaves out of a command buffer (VLOG 2), both into DUMP_DIR (large); an empty compile
    # cache of its own, since a program loaded from the cache is neither compiled nor dumped
    rm -rf "$DUMP_DIR"; mkdir -p "$DUMP_DIR"; log="$DUMP_DIR/overlap.log"
    flags="$flags --xla_dump_to=$DUMP_DIR --xla_dump_hlo_as_text --xla_dump_hlo_module_re=$DUMP_MODULES"
    vlog=(TF_CPP_MIN_LOG_LEVEL=0 "TF_CPP_VMODULE=$VMODULE" "JAX_COMPILATION_CACHE_DIR=$DUMP_DIR/jax_cache")
  fi
  stamp "overlap $name"
  # shellcheck disable=SC2086
  env "${vlog[@]}" XLA_FLAGS="$flags" timeout "$STEP_TIMEOUT" \
    python3 bench/stream_overlap.py --plain $OVERLAP_ARGS --env-overrides cholesky="${CHOL_OF[$name]:-library}" \
    --out "$OUT/overlap_$name.md" > "$log" 2>&1
  stamp "  rc $?"
  if [ "${DUMP:-0}" = 1 ]; then
    grep -vE "$XLA_INFO" "$log" > "$OUT/overlap_$name.log"  # the log without XLA's info lines
    python3 bench/command_buffers.py "$DUMP_DIR" --module "$DUMP_MODULES" --out "$OUT/command_buffers_$name.md" \
      > /dev/null 2>&1
    stamp "  command buffers: rc $? ($(du -sh "$DUMP_DIR" 2>/dev/null | cut -f1) of dump)"
    cb_reasons "$log" > "$OUT/command_buffer_log_overlap_$name.md"
  fi
fi

{
  echo "capture variants, $(python3 -c 'import jax; print(jax.devices()[0].device_kind, "jax", jax.__version__)' 2>/dev/null)"
  for name in "${NAMES[@]}"; do
    echo; echo "## $name (cholesky=${CHOL_OF[$name]}, XLA_FLAGS '${FLAGS_OF[$name]}')"
    grep -E '^\| (env|rollout|update|epoch|loop)' "$OUT/breakdown_$name.md" 2>/dev/null \
      || tail -5 "$OUT/breakdown_$name.log"
  done
  for f in "$OUT"/overlap_*.md "$OUT"/command_buffer_log_*.md "$OUT"/command_buffers_*.md; do
    [ -f "$f" ] && { echo; cat "$f"; }
  done
} > "$OUT/summary_capture.md"
cat "$OUT/summary_capture.md"
