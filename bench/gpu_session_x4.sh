#!/usr/bin/env bash
# One nvidia-h200-x4 call (about 8 minutes): everything multi-GPU in one call.
#
#   phase 1:               training on 1 GPU (GPU 2)
#   phase 2 (in parallel): training on 2 GPUs (0,1)           | 2 processes, one per GPU, jax.distributed (2,3)
#   phase 3:               training on 4 GPUs (0-3)
#   then a results table (bench/session_summary.py) printed last.
#
# Same per-device batch everywhere: 4096 envs and batch_size 256 per GPU (the gpu preset per device since
# 2026-11-27; BATCH=512 for the figures before it).
# Each training run stops at a wall-clock budget (--max-minutes, from process start, compile included),
# evaluates every 2 progress lines of 10 iterations, and skips the ONNX export. Each step has its own
# timeout, so one hang cannot eat the call. Work goes to $WORK; $OUT gets 2 files (the device tool brings
# back at most 8): summary.md (the table printed last) and session_x4.tgz (logs, metrics, configs).
#
# Usage (repository root, after the pip prefix of /work/shared/gpu/README.md):
#   bash bench/gpu_session_x4.sh            # on nvidia-h200-x4
#   bash bench/gpu_session_x4.sh --smoke    # CPU logic check: forced host devices, tiny sizes
#   SHORT=1 bash bench/gpu_session_x4.sh    # scaling only: 1 GPU | 2 GPUs side by side, then 4 GPUs
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
OUT=${OUT:-/tmp/session_x4_out}
WORK=${WORK:-/tmp/session_x4}
mkdir -p "$OUT" "$WORK"
export PYTHONUNBUFFERED=1
SMOKE=0
[ "${1:-}" = "--smoke" ] && SMOKE=1
export JAX_COMPILATION_CACHE_DIR=${JAX_COMPILATION_CACHE_DIR:-/tmp/jaxcache_x4}
T0=$(date +%s)
# Bytecode for what is on PYTHONPATH: a pip install writes it, the lent machine's --no-compile prefix does
# not (the warm run's imports 3.4 -> 2.4 s on an H100 machine, 2026-11-27).
[ -z "${PYTHONPATH:-}" ] || python3 -m compileall -q -j 0 ${PYTHONPATH//:/ } > /dev/null 2>&1 || true
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*"; }

if [ $SMOKE = 1 ]; then
  export JAX_PLATFORMS=cpu
  PER_DEV="--preset tiny --ppo.num-timesteps 2048 --log-every-iterations 1"
  ENVS=16; BATCH=16; MINUTES=6; FINAL=16
  T_TRAIN=900
else
  PER_DEV="--ppo.num-timesteps 400000000 --log-every-iterations 10"
  ENVS=4096; BATCH=${BATCH:-256}; MINUTES=2.0; FINAL=1024
  T_TRAIN=170
fi
COMMON="--runs-dir $WORK/runs --no-export-onnx --final-eval-envs $FINAL --max-minutes $MINUTES"

# gpus LIST N: select GPUs (CUDA_VISIBLE_DEVICES) or, in smoke mode, N forced CPU devices.
gpus() { if [ $SMOKE = 1 ]; then echo "XLA_FLAGS=--xla_force_host_platform_device_count=$2"; \
         else echo "CUDA_VISIBLE_DEVICES=$1"; fi; }

train() {  # train NAME GPU_LIST N
  local n=$3
  stamp "train $1 on $n device(s) ($2)"
  env $(gpus "$2" "$n") timeout -k 10 $T_TRAIN python3 train/ppo.py --run-name "$1" $COMMON $PER_DEV \
    --ppo.num-envs $((ENVS * n)) --ppo.batch-size $((BATCH * n)) > "$WORK/$1.log" 2>&1
  stamp "train $1 exit $?"
}

two_process() {  # jax.distributed on localhost, one process per device
  local port=$((20000 + RANDOM % 20000))
  local d="--distributed.coordinator-address 127.0.0.1:$port --distributed.num-processes 2"
  stamp "2 processes (jax.distributed) on 2,3"
  for pid in 0 1; do
    local ids="--distributed.local-device-ids $pid"
    [ $SMOKE = 1 ] && ids=""
    env $(gpus 2,3 1) timeout -k 10 $T_TRAIN python3 train/ppo.py --run-name dist2 $COMMON $PER_DEV $d \
      --distributed.process-id $pid $ids --ppo.num-envs $((ENVS * 2)) --ppo.batch-size $((BATCH * 2)) \
      > "$WORK/dist2_p$pid.log" 2>&1 &
  done
  wait
  stamp "2 processes done"
}

summary() {
  tar -czf "$OUT/session_x4.tgz" -C "$WORK" --exclude='*.msgpack' --exclude='tb' . 2>/dev/null
  python3 bench/session_summary.py "$WORK/runs/g1" "$WORK/runs/g2" "$WORK/runs/g4" "$WORK/runs/dist2" \
    --out "$OUT/summary.md"
}

if [ "${SHORT:-0}" = 1 ]; then  # scaling only (about 5 min): 1 GPU | 2 GPUs side by side, then 4 GPUs
  MINUTES=${MINUTES_SHORT:-1.7}
  COMMON="--runs-dir $WORK/runs --no-export-onnx --final-eval-envs $FINAL --max-minutes $MINUTES"
  stamp "short: 1 device (0) | 2 devices (1,2)"
  train g1 0 1 &
  train g2 1,2 2 &
  wait
  summary > /dev/null
  train g4 0,1,2,3 4
  summary
  exit 0
fi

stamp "phase 1: 1 device"
train g1 2 1
stamp "phase 2: 2 devices | 2 processes"
train g2 0,1 2 &
two_process &
wait
stamp "phase 3: 4 devices"
train g4 0,1,2,3 4

for f in g1 g2 g4 dist2_p0 dist2_p1; do
  echo "== $f (tail)"; grep -v "^WARNING\|^I0000\|^W0000" "$WORK/$f.log" 2>/dev/null | tail -n 4
done
stamp "session done"
summary
