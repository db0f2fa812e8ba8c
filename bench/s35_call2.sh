set -u
T0=$(date +%s)
python3 -m compileall -q -j 0 /tmp/site $PWD/bar_policy $PWD/train >/dev/null 2>&1
el() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
el start
OUT_MAIN=$OUT
OUT=$OUT_MAIN/startup COLD_WARM_ONLY=1 COLD_MIN=1.9 WARM_MIN=1.1 timeout 330 bash bench/gpu_session_h100.sh startup > $OUT_MAIN/startup.log 2>&1
el "startup rc $?"; tail -30 $OUT_MAIN/startup.log
timeout 150 python3 bench/train_breakdown.py --iters 3 --epoch-iters 4 --out $OUT_MAIN/bd.md > $OUT_MAIN/bd.log 2>&1
el "breakdown rc $?"; grep -v Warn $OUT_MAIN/bd.log | tail -18
timeout 120 python3 bench/program_split.py --sets rollout --profile /tmp/prof --timeout 100 --out $OUT_MAIN/prof.md > $OUT_MAIN/prof.log 2>&1
el "profile rc $?"; tail -95 $OUT_MAIN/prof.md
