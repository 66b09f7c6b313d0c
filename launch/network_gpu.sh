#!/usr/bin/env bash
# The network task (issue 42) on one CUDA GPU in one go: train `experiment=network device=cuda`
# with a GPU batch for MINUTES, then evaluate the last checkpoint on held-out scenes at the
# difficulty it reached and at 4. Run from the repository root:
#
#   launch/network_gpu.sh OUT [MINUTES]          (MINUTES: default 4, whole or decimal)
#
# Environment: ENVS (batched trucks, default 8192), STEPS (steps per env and rollout, default
# 32), POOL (episodes drawn per refill of the reset pool, default 8192: the scene generator's
# fixed costs per draw dominate), EPISODES (held-out scenes per evaluation, default 1000), SEED
# (their seed, default 12345), EXTRA (more training overrides, words), PY (default python3),
# WHEELS (a folder of wheels installed into /tmp/site where torchrl or hydra is missing,
# default .wheels), DEVICE (default cuda; a dry run on a CPU: DEVICE=cpu ENVS=64 STEPS=8
# POOL=64 EPISODES=8 EXTRA="env.compile=false collector.compile_policy=false").
#
# Writes into OUT: device.txt, train.log (the trainer's output), train_run.log (the run's own
# log), last.pt, reached.json (frames, difficulty, success EMA of the last checkpoint),
# eval_reached.json / eval_4.json and their .log, summary.txt. The training stops itself at
# MINUTES (a `timeout` 150 s later kills a hung one); whatever it saved is evaluated even when
# it failed, and a missing checkpoint ends the script with a non-zero exit after writing what
# it has. With the defaults it takes about MINUTES + 3 minutes (compilation, two evaluations).
set -euo pipefail
OUT=${1:?usage: launch/network_gpu.sh OUT [MINUTES]}
MIN=${2:-4}
ENVS=${ENVS:-8192}
STEPS=${STEPS:-32}
POOL=${POOL:-8192}
EPISODES=${EPISODES:-1000}
SEED=${SEED:-12345}
PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
WHEELS=${WHEELS:-.wheels}
RUN="$OUT/run"
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
t0=$SECONDS
say() { echo "[network_gpu +$((SECONDS - t0)) s] $*" | tee -a "$OUT/summary.txt"; }

if ! "$PY" -c 'import torchrl, tensordict, hydra' 2>/dev/null; then
    if [ -d "$WHEELS" ]; then
        say "installing the wheels of $WHEELS into /tmp/site"
        "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
            --target /tmp/site "$WHEELS"/*.whl
        export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
    fi
fi
{ nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
  "$PY" -c 'import torch, torchrl, tensordict; print("torch", torch.__version__, "torchrl", torchrl.__version__, "tensordict", tensordict.__version__, torch.cuda.get_device_name() if torch.cuda.is_available() else "no GPU")' || true
  nproc; } 2>&1 | tee "$OUT/device.txt"

say "training experiment=network device=$DEVICE, $ENVS trucks x $STEPS steps, $MIN min"
rc=0
timeout "$(awk "BEGIN {print int($MIN * 60 + 150)}")" "$PY" -m truckrl.train \
    experiment=network device="$DEVICE" collector.num_envs="$ENVS" collector.steps_per_env="$STEPS" \
    env.episode_pool="$POOL" ppo.compile=false max_minutes="$MIN" hydra.run.dir="$RUN" \
    overwrite=true log.progress_bar=false log.video_interval=0 log.eval_interval_min=0 \
    ${EXTRA:-} >"$OUT/train.log" 2>&1 || rc=$?
tail -n 25 "$OUT/train.log"
say "training exit $rc"
cp "$RUN/train.log" "$OUT/train_run.log" 2>/dev/null || true
CKPT="$RUN/checkpoints/last.pt"
if [ ! -f "$CKPT" ]; then
    say "no checkpoint at $CKPT: nothing to evaluate"
    exit 1
fi
cp "$CKPT" "$OUT/last.pt"
"$PY" - "$CKPT" >"$OUT/reached.json" <<'PY'
import json, sys
import torch
state = torch.load(sys.argv[1], map_location="cpu", weights_only=False)
cur, counters = state.get("curriculum", {}), state.get("counters", {})
print(json.dumps({
    "difficulty": float(cur.get("difficulty", 0.0)),
    "success_ema": float(cur.get("ema", 0.0)),
    "promotions": cur.get("promotions"),
    "counters": {k: (v if isinstance(v, (int, float)) else str(v)) for k, v in counters.items()},
}, indent=1, default=str))
PY
REACHED=$("$PY" -c 'import json, sys; print(json.load(open(sys.argv[1]))["difficulty"])' \
    "$OUT/reached.json")
say "checkpoint: $(tr -d '\n' <"$OUT/reached.json")"

fails=0
for d in "$REACHED" 4; do
    name=eval_reached; [ "$d" = 4 ] && name=eval_4
    [ "$d" = 4 ] && [ "$REACHED" = 4.0 ] && continue
    say "evaluating at difficulty $d on $EPISODES held-out scenes (seed $SEED)"
    if "$PY" -m truckrl.evaluate checkpoint="$CKPT" difficulty="$d" episodes="$EPISODES" \
        seed="$SEED" device="$DEVICE" output="$OUT/$name.json" >"$OUT/$name.log" 2>&1; then
        say "$name: $("$PY" - "$OUT/$name.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
bins = {f'{c["dimension"]}/{c["bin"]}': (c["count"], round(c["success_rate"], 3))
        for c in r.get("categories", [])}
print({k: r.get(k) for k in ("difficulty", "episodes", "success_rate", "collision_rate",
                             "timeout_rate")}, bins)
PY
)"
    else
        fails=$((fails + 1)); tail -n 20 "$OUT/$name.log"; say "$name failed"
    fi
done
say "done: training exit $rc, $fails evaluation(s) failed"
exit $(( rc != 0 ? 1 : fails ))
