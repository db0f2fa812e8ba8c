set -u
T0=$(date +%s)
python3 -m compileall -q -j 0 /tmp/site $PWD/bar_policy $PWD/train >/dev/null 2>&1
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
CB="FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,DYNAMIC_SLICE_FUSION"
run() {  # NAME TIMEOUT FLAGS ARGS
  local name=$1 to=$2 flags=$3; shift 3
  echo "== $name (XLA_FLAGS=$flags) at $(( $(date +%s) - T0 )) s"
  XLA_FLAGS="$flags" timeout $to python3 bench/train_breakdown.py --iters 3 --epoch-iters 4 --out $OUT/bd_$name.md "$@" > $OUT/bd_$name.log 2>&1
  echo "rc $?"; grep -v "^$" $OUT/bd_$name.log | grep -v Warning | tail -16
}
run default 190 "" --fused
run while 170 "--xla_gpu_enable_command_buffer=$CB,WHILE,CONDITIONAL"
run while_min1 150 "--xla_gpu_enable_command_buffer=$CB,WHILE,CONDITIONAL --xla_gpu_graph_min_graph_size=1"
echo "done at $(( $(date +%s) - T0 )) s"
