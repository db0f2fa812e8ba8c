#!/usr/bin/env bash
# Two GPUs of one host (nvidia-h100-x2 / nvidia-h200-x2), one call of about 6 minutes:
#
#   g2_cold  both GPUs, one process (a 2-device mesh), empty compile cache (the shipped autotune seed applies
#            where the device kind has one)
#   g2_warm  the same command again on the same cache (the executable cache loads every program)
#   g1       GPU 0 alone, empty cache of its own (1-device programs differ), the baseline of the ratio
#
# Same per-device sizes everywhere: the gpu preset (4096 envs, batch_size 256 since 2026-11-27; BATCH=512
# for the figures before it) per GPU. Each run stops at
# a wall-clock budget from process start (--max-minutes), skips the ONNX export, and has its own timeout.
# $OUT gets summary_x2.md (bench/session_summary.py: steady env steps/s = median of the progress lines
# after the first; "x first" = ratio to the first run listed, g1) and session_x2.tgz (logs, metrics).
#
# TRAIN_ARGS: more arguments for every run (e.g. "--ppo.update-precision tensorfloat32"); NO_WARM=1 skips
# g2_warm (about 3.5 minutes then).
#
# Usage (repository root, after the pip prefix of /work/shared/gpu/README.md): bash bench/gpu_session_x2.sh
#   --smoke: CPU logic check with two forced host devices and tiny sizes.
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1 PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/session_x2_out}
WORK=${WORK:-/tmp/session_x2}
mkdir -p "$OUT" "$WORK"
T0=$(date +%s)
# Bytecode for what is on PYTHONPATH: a pip install writes it, the lent machine's --no-compile prefix does
# not (the warm run's imports 3.4 -> 2.4 s on an H100 machine, 2026-11-27).
[ -z "${PYTHONPATH:-}" ] || python3 -m compileall -q -j 0 ${PYTHONPATH//:/ } > /dev/null 2>&1 || true
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
ENVS=4096; BATCH=${BATCH:-256}; FINAL=1024; TS=1; SIZES=""
if [ "${1:-}" = "--smoke" ]; then
  export JAX_PLATFORMS=cpu
  ENVS=16; BATCH=16; FINAL=16; TS=6; SIZES="--preset tiny --ppo.num-timesteps 2048"
fi
devices() {  # devices LIST N: the GPUs a run sees (smoke: N forced CPU devices)
  if [ -n "$SIZES" ]; then echo "XLA_FLAGS=--xla_force_host_platform_device_count=$2"; else echo "CUDA_VISIBLE_DEVICES=$1"; fi
}
train() {  # train NAME GPU_LIST N CACHE MINUTES TIMEOUT_S
  stamp "train $1 on $3 device(s) ($2), cache $4, --max-minutes $5"
  env $(devices "$2" "$3") timeout -k 10 $(($6 * TS)) python3 train/ppo.py --run-name "$1" --runs-dir "$WORK/runs" \
    --no-export-onnx --final-eval-envs $FINAL --compile-cache-dir "$4" --max-minutes "$5" $SIZES \
    --ppo.num-envs $((ENVS * $3)) --ppo.batch-size $((BATCH * $3)) ${TRAIN_ARGS:-} > "$WORK/$1.log" 2>&1
  stamp "train $1 exit $?"
  grep -v "^WARNING\|^I0000\|^W0000" "$WORK/$1.log" | grep -A14 "^start-up" | head -n 16
}
finish() {
  tar -czf "$OUT/session_x2.tgz" -C "$WORK" --exclude='*.msgpack' --exclude='tb' --exclude='cache*' . 2>/dev/null
  python3 bench/session_summary.py "$WORK"/runs/g1 "$WORK"/runs/g2_* --out "$OUT/summary_x2.md"
}
rm -rf "$WORK"/cache2 "$WORK"/cache1
train g2_cold 0,1 2 "$WORK/cache2" "${COLD_MIN:-1.8}" 170
finish > /dev/null
if [ -z "${NO_WARM:-}" ]; then
  train g2_warm 0,1 2 "$WORK/cache2" "${WARM_MIN:-1.2}" 120
  finish > /dev/null
fi
train g1 0 1 "$WORK/cache1" "${G1_MIN:-1.6}" 150
finish
