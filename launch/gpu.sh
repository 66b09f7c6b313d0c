#!/usr/bin/env bash
# The GPU figures of docs/benchmarks.md ("GPU"), in one go, on a machine with one CUDA GPU and
# truckrl's dependencies importable. Run from the repository root:
#
#   launch/gpu.sh OUT [checks|train|demos|quality|precision|controls|reverse|all] [MINUTES]
#
#   checks: the CUDA tests (tests/test_device.py: no host sync in env.step, a collector + PPO
#           iteration that stays on the GPU), `bench env device=cuda` at N = 4,096 ... 262,144
#           and `bench train device=cuda experiment=gpu` at 32,768 trucks, 8 minibatches;
#   train:  `python -m truckrl.train experiment=gpu` until difficulty 6 or MINUTES (default 8);
#   demos:  `python -m truckrl.train experiment=gpu_demos stop_difficulty=6` until difficulty 6 or
#           MINUTES (whole minutes); if it fails within its first 150 s (a compile error, say),
#           once more with the policy, the loss and the planner eager (the env stays compiled).
#           Writes demos_perf.json: the promotions and the medians of the per-iteration
#           timings, read from its TensorBoard log;
#   quality: `python -m truckrl.train experiment=gpu_demos stop_on_quality=true` until training's
#           held-out check first reads log.quality_target (0.95) at difficulty 6 (quality_reached),
#           or MINUTES, with held-out checks every EVAL_FRAMES frames (default 10,000,000); then
#           its last checkpoint on 1,000 held-out scenes (seed 12345) at difficulty 6;
#   precision: `python -m truckrl.train experiment=gpu_d8` (the shipped intersection policy, or
#           INIT, fine-tuned from difficulty 6 up to 8: 0.117 m, 0.23 deg) until training's
#           held-out check first reads 0.90 at difficulty 8, its 60 M frames, or MINUTES; then
#           INIT, the run's last.pt and its best.pt on
#           1,000 held-out scenes (seed 12345) at difficulty 8, and last.pt at 6 (precision_*.json);
#   controls: `experiment=gpu_demos control=C` for each C of CONTROLS (default "jerk_accel
#           accel_rate"), side by side on the one GPU, each for MINUTES; then each run's last.pt
#           and best.pt on 1,000 held-out scenes (seed 12345) at difficulty 6, with the smoothness
#           of their successful episodes (controls_<C>_<last|best>.json). Each run gets an
#           equal share of the host's cores (threads=): two runs of 16 threads each on 16 cores
#           stalled for minutes after their planning. EXTRA (words) adds
#           training overrides, DEVICE (default cuda) is the evaluations' device: a dry run on
#           a CPU is EXTRA="device=cpu collector.num_envs=64 ..." DEVICE=cpu;
#   reverse: `experiment=gpu_dock` (finetune_dock on the GPU) and `experiment=gpu_uturn` (the
#           shipped reversing policies fine-tuned: dock at difficulty 7, uturn from 4 up to 6), side by side on the one
#           GPU with half the host's cores each, each stopped by its frame budget or MINUTES;
#           their best.pt and last.pt land in OUT as reverse_<task>_<best|last>.pt, the two run
#           folders' logs and TensorBoard events in reverse_runs.tar.gz (score them on a CPU:
#           `truckrl eval checkpoint=FILE difficulty=7|6 episodes=1000 seed=12345`);
#
# Logs, JSON and the runs' train.log and last checkpoint land flat in OUT; the run folders
# themselves go to RUNS (default outputs/gpu). Every step runs even if an earlier one fails; the
# exit code is the number of failures.
set -u
OUT=${1:?usage: launch/gpu.sh OUT [checks|train|demos|quality|precision|controls|reverse|all] [MINUTES]}
WHAT=${2:-all}
MIN=${3:-8}
RUNS=${RUNS:-outputs/gpu}
mkdir -p "$OUT" "$RUNS"
export PYTHONUNBUFFERED=1
fails=0
step() {  # step NAME COMMAND...: run, tee the log into OUT/NAME.log, count a failure
    local name=$1; shift
    echo "=== $name: $*"
    local t0=$SECONDS
    "$@" >"$OUT/$name.log" 2>&1; local rc=$?
    tail -n 40 "$OUT/$name.log"
    echo "=== $name: exit $rc after $((SECONDS - t0)) s"
    [ $rc -eq 0 ] || fails=$((fails + 1))
}

{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
  python3 -c 'import torch, torchrl, tensordict; print("torch", torch.__version__, "torchrl", torchrl.__version__, "tensordict", tensordict.__version__, torch.cuda.get_device_name())'
  nproc; command -v g++ || echo "no g++"; } 2>&1 | tee "$OUT/device.txt"

if [ "$WHAT" = checks ] || [ "$WHAT" = all ]; then
    step tests python3 -m pytest -q -p no:cacheprovider tests/test_device.py -rs
    step bench_env python3 -m truckrl.bench env device=cuda "envs=[4096,65536,262144]" paper=false \
        "out=$OUT"
    step bench_train python3 -m truckrl.bench train device=cuda experiment=gpu \
        collector.num_envs=32768 ppo.num_minibatches=8 "out=$OUT/bench_train.json"
fi
if [ "$WHAT" = train ] || [ "$WHAT" = all ]; then
    step train python3 -m truckrl.train experiment=gpu max_minutes="$MIN" \
        hydra.run.dir="$RUNS/train" log.progress_bar=false log.video_interval=0
    cp "$RUNS/train/train.log" "$OUT/train_run.log"; cp "$RUNS/train/checkpoints/last.pt" "$OUT/train_last.pt"
fi
if [ "$WHAT" = demos ]; then
    demos() {  # demos EXTRA_OVERRIDES...
        step demos timeout $((MIN * 60 + 90)) python3 -m truckrl.train experiment=gpu_demos \
            stop_difficulty=6 max_minutes="$MIN" hydra.run.dir="$RUNS/demos" overwrite=true \
            log.progress_bar=false log.video_interval=0 "$@"
    }
    t0=$SECONDS; before=$fails
    demos
    if [ $fails -gt $before ] && [ $((SECONDS - t0)) -lt 150 ]; then
        demos ppo.compile=false collector.compile_policy=false demos.compile=false
    fi
    cp "$RUNS/demos/train.log" "$OUT/demos_run.log"; cp "$RUNS/demos/checkpoints/last.pt" "$OUT/demos_last.pt"
    python3 - "$RUNS/demos" >"$OUT/demos_perf.json" <<'PY'
import json, sys
import numpy as np
from truckrl.viz.curves import load_scalars, milestones
s = load_scalars(sys.argv[1])
med = {k: float(np.median(v[:, 2])) for k, v in s.items() if k.startswith("perf/")}
first = {k: float(v[0, 2]) for k, v in s.items() if k.startswith("perf/")}
print(json.dumps({"milestones": milestones(s), "median": med, "first_iteration": first,
                  "iterations": int(len(s["perf/fps"]))}, indent=1))
PY
fi
if [ "$WHAT" = quality ]; then
    step quality timeout $((MIN * 60 + 90)) python3 -m truckrl.train experiment=gpu_demos \
        stop_on_quality=true max_minutes="$MIN" log.eval_interval_frames="${EVAL_FRAMES:-10000000}" \
        hydra.run.dir="$RUNS/quality" overwrite=true log.progress_bar=false log.video_interval=0
    cp "$RUNS/quality/train.log" "$OUT/quality_run.log"
    grep -h "quality_reached" "$RUNS/quality/train.log" | tee "$OUT/quality_reached.txt"
    step quality_eval python3 -m truckrl.evaluate checkpoint="$RUNS/quality" difficulty=6 \
        episodes=1000 seed=12345 device=cuda output="$OUT/quality_eval.json"
fi
if [ "$WHAT" = precision ]; then
    INIT=${INIT:-pretrained:intersection}
    step precision timeout $((MIN * 60 + 90)) python3 -m truckrl.train experiment=gpu_d8 \
        init="$INIT" stop_on_quality=true max_minutes="$MIN" \
        hydra.run.dir="$RUNS/precision" overwrite=true log.progress_bar=false log.video_interval=0
    cp "$RUNS/precision/train.log" "$OUT/precision_run.log"
    for k in last best; do cp "$RUNS/precision/checkpoints/$k.pt" "$OUT/precision_$k.pt"; done
    ev() {  # ev NAME CHECKPOINT DIFFICULTY
        step "precision_$1" python3 -m truckrl.evaluate checkpoint="$2" difficulty="$3" \
            episodes=1000 seed=12345 device=cuda output="$OUT/precision_$1.json" &
    }
    ev init_d8 "$INIT" 8; ev last_d8 "$RUNS/precision/checkpoints/last.pt" 8
    ev best_d8 "$RUNS/precision/checkpoints/best.pt" 8; ev last_d6 "$RUNS/precision/checkpoints/last.pt" 6
    wait
    for k in init_d8 last_d8 best_d8 last_d6; do [ -f "$OUT/precision_$k.json" ] || fails=$((fails + 1)); done
fi
if [ "$WHAT" = controls ]; then
    runs=(${CONTROLS:-jerk_accel accel_rate})
    share=$(( $(nproc) / ${#runs[@]} )); [ "$share" -ge 1 ] || share=1
    for c in "${runs[@]}"; do
        step "controls_$c" timeout $((MIN * 60 + 120)) python3 -m truckrl.train \
            experiment=gpu_demos control="$c" max_minutes="$MIN" \
            log.eval_interval_frames="${EVAL_FRAMES:-20000000}" hydra.run.dir="$RUNS/controls_$c" \
            overwrite=true log.progress_bar=false log.video_interval=0 threads="$share" ${EXTRA:-} &
    done
    wait  # the steps ran in subshells: failures are counted from what they left below
    for c in ${CONTROLS:-jerk_accel accel_rate}; do
        cp "$RUNS/controls_$c/train.log" "$OUT/controls_${c}_run.log"
        for k in last best; do cp "$RUNS/controls_$c/checkpoints/$k.pt" "$OUT/controls_${c}_$k.pt"; done
        for k in last best; do
            step "controls_${c}_$k" python3 -m truckrl.evaluate \
                checkpoint="$RUNS/controls_$c/checkpoints/$k.pt" difficulty=6 episodes=1000 \
                seed=12345 device="${DEVICE:-cuda}" output="$OUT/controls_${c}_$k.json" &
        done
    done
    wait
    for c in ${CONTROLS:-jerk_accel accel_rate}; do
        for k in last best; do [ -f "$OUT/controls_${c}_$k.json" ] || fails=$((fails + 1)); done
    done
fi
if [ "$WHAT" = reverse ]; then
    share=$(( $(nproc) / 2 )); [ "$share" -ge 1 ] || share=1
    for t in dock uturn; do
        step "reverse_$t" timeout $((MIN * 60 + 60)) python3 -m truckrl.train \
            experiment="gpu_$t" max_minutes="$MIN" hydra.run.dir="$RUNS/reverse_$t" overwrite=true \
            log.progress_bar=false log.video_interval=0 threads="$share" ${EXTRA:-} &
    done
    wait  # the steps ran in subshells: failures are counted from what they left below
    for t in dock uturn; do
        for k in last best; do
            cp "$RUNS/reverse_$t/checkpoints/$k.pt" "$OUT/reverse_${t}_$k.pt" || fails=$((fails + 1))
        done
        grep -h "quality_reached\|best.pt\|difficulty" "$RUNS/reverse_$t/train.log" | tail -n 30
    done
    tar -czf "$OUT/reverse_runs.tar.gz" -C "$RUNS" --exclude='*.pt' reverse_dock reverse_uturn
fi
exit $fails
