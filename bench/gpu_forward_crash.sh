#!/usr/bin/env bash
# Narrow the multi-GPU compile crash of mjx.forward (issue 9) in one ~3-minute call on nvidia-h200-x2:
# the bisect's finer stages, then `forward` under XLA flag variants, then one single-GPU control; a native
# backtrace with gdb when the machine has it. Each piece is its own process (a segfault is a table row).
#   bash bench/gpu_forward_crash.sh          (repository root, after the pip prefix of ../shared/gpu)
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1 PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/fwd_crash_out}; mkdir -p "$OUT/logs"
B="python3 bench/pmap_reset_bisect.py --no-torch-variant --envs-per-device 128 --timeout 150"
CUDA_VISIBLE_DEVICES=0,1 $B --parallel 8 --out "$OUT/stages.md" --logs "$OUT/logs/stages" \
  --stages ${STAGES:-forward,cholesky,while_loop,forward_cg,forward_noconstraint,fwd_position,shard_forward,shard_step} \
  > "$OUT/stages.log" 2>&1 &
i=0
for f in --xla_gpu_force_compilation_parallelism=1 --xla_gpu_enable_triton_gemm=false \
         --xla_gpu_enable_cublaslt=false --xla_gpu_enable_dynamic_slice_fusion=false \
         --xla_gpu_enable_llvm_module_compilation_parallelism=false --xla_gpu_autotune_level=0; do
  i=$((i + 1))
  XLA_FLAGS=$f CUDA_VISIBLE_DEVICES=0,1 $B --stages forward --out "$OUT/flag$i.md" \
    --logs "$OUT/logs/flag$i" > "$OUT/flag$i.log" 2>&1 &
done
CUDA_VISIBLE_DEVICES=0 $B --stages forward,shard_step --out "$OUT/one_gpu.md" --logs "$OUT/logs/one" \
  > "$OUT/one.log" 2>&1 &
if command -v gdb > /dev/null; then
  CUDA_VISIBLE_DEVICES=0,1 XLA_PYTHON_CLIENT_PREALLOCATE=false timeout 150 gdb -batch -ex run -ex bt \
    --args python3 bench/pmap_reset_bisect.py --child --stage forward --envs-per-device 2 \
    > "$OUT/gdb.log" 2>&1 &
else
  echo "no gdb" > "$OUT/gdb.log"
fi
wait
cat "$OUT/stages.md"
i=0
for f in force_compilation_parallelism=1 triton_gemm=false cublaslt=false dynamic_slice_fusion=false \
         llvm_module_compilation_parallelism=false autotune_level=0; do
  i=$((i + 1)); echo "flag $f: $(grep '^| forward' "$OUT/flag$i.md" 2>/dev/null || tail -n 1 "$OUT/flag$i.log")"
done
echo "one GPU:"; grep '^| ' "$OUT/one_gpu.md" | tail -n 2
grep -A25 "SIGSEGV" "$OUT/gdb.log" | grep "^#" | head -n 25 || tail -n 5 "$OUT/gdb.log"
