"""Device placement: what keeps ``device=cuda`` correct on a machine without a GPU.

The CUDA path is guarded three ways (the CUDA-only tests ran on an H100, docs/benchmarks.md, GPU):

* a static scan of the step path (simulator, tasks, env adapter, PPO): every tensor factory call
  names its ``device=``, except the listed host-side helpers (oracles, index tables that move with
  their module);
* every task moves all of its tensors with :meth:`Task.to` (checked on the ``meta`` device, which
  any torch build has);
* with a GPU present, the env steps with ``torch.cuda.set_sync_debug_mode("error")`` (no host sync
  in the step path) and one collector + PPO iteration keeps every tensor on the GPU. These skip on
  CPU-only machines.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import torch

import truckrl

ROOT = Path(truckrl.__file__).parent

#: Task-folder modules off the step path (demonstrations, diagnostics and a folder's own
#: commands run host side), and folders whose modules all are.
OFF_STEP_PATH = {"expert.py", "diagnosis.py", "tools.py"}
OFF_STEP_DIRS = {"expert", "tools"}


def _on_step_path(p: Path) -> bool:
    """A module of ``truckrl/tasks`` that is not off the step path by name or folder."""
    return p.name not in OFF_STEP_PATH and not OFF_STEP_DIRS & set(p.relative_to(ROOT).parts[2:-1])


#: Files on the step and update path.
STEP_PATH = sorted(
    [*(ROOT / "sim").glob("*.py"), *(ROOT / "env").glob("*.py")]
    + [p for p in (ROOT / "tasks").rglob("*.py") if _on_step_path(p)]
    + [ROOT / "rl" / f for f in ("ppo.py", "network.py", "collection.py", "metrics.py")]
)
FACTORIES = {"zeros", "ones", "full", "empty", "arange", "tensor", "as_tensor", "rand", "randn"}
FACTORIES |= {"randint", "randperm", "linspace", "eye"}

#: (file, function) pairs allowed to build tensors on the default device, and why.
HOST_SIDE = {
    ("sim/lidar.py", "lidar_oracle"): "per-ray reference implementation, float64 on the host",
    ("sim/lidar.py", "__call__"): "SweepLidar: the paper's single-scene sweep, host side",
    ("tasks/base.py", "__init__"): "param_index: moved by Task.to",
    ("tasks/network/task.py", "__init__"): "curriculum tables: moved by NetworkTask.to",
    ("env/truck_env.py", "__init__"): "draws a Python int seed",
    ("env/truck_env.py", "_set_seed"): "draws a Python int seed",
    ("rl/network.py", "circular_conv_index"): "index table: a module buffer, moves with .to",
    ("rl/network.py", "__init__"): "parameters and buffers: move with .to",
}


def _factory_calls_without_device(path: Path) -> list[tuple[str, int, str]]:
    tree = ast.parse(path.read_text())
    owner: dict[int, str] = {}
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            for node in ast.walk(fn):
                owner[id(node)] = fn.name  # innermost last: walk visits nested functions later
    found = []
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and isinstance(node.func.value, ast.Name)
            and node.func.value.id == "torch"
            and node.func.attr in FACTORIES
            and not any(k.arg == "device" for k in node.keywords)
        ):
            found.append((owner.get(id(node), "<module>"), node.lineno, node.func.attr))
    return found


def test_step_path_tensors_name_their_device():
    bad = []
    for path in STEP_PATH:
        rel = path.relative_to(ROOT).as_posix()
        for fn, line, name in _factory_calls_without_device(path):
            if (rel, fn) not in HOST_SIDE:
                bad.append(f"truckrl/{rel}:{line} torch.{name}(...) in {fn}() has no device=")
    assert not bad, "tensors created on the default device in the step path:\n" + "\n".join(bad)


def test_the_scan_finds_a_factory_without_device(tmp_path):
    f = tmp_path / "x.py"
    f.write_text("import torch\ndef g(n, d):\n    a = torch.zeros(n, device=d)\n"
                 "    return torch.arange(n) + a\n")  # fmt: skip
    assert _factory_calls_without_device(f) == [("g", 4, "arange")]


@pytest.mark.parametrize("name", ["intersection", "dock", "uturn"])
def test_task_to_moves_every_tensor(name):
    from truckrl.tasks import EnvConfig, make_task

    task = make_task(EnvConfig(task={"name": name})).to("meta")
    stray = {k: v.device for k, v in vars(task).items() if torch.is_tensor(v)}
    stray = {k: d for k, d in stray.items() if d.type != "meta"}
    assert not stray, f"Task.to left tensors behind: {stray}"


cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


@cuda
@pytest.mark.parametrize("compile_env", [False, True])
def test_cuda_step_path_has_no_host_sync(compile_env):
    from truckrl.env import TruckEnv

    # The step itself; a reset reads the reset mask on the host once per call (nonzero), by design.
    env = TruckEnv(num_envs=256, device="cuda", seed=0, config={"compile": compile_env})
    td = env.reset()
    action = torch.zeros(256, 2, device="cuda")
    for _ in range(3):  # warm-up: compilation may sync
        td = env.step(td.set("action", action))["next"]
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        for _ in range(20):
            td = env.step(td.set("action", torch.rand_like(action) * 2 - 1))["next"]
    finally:
        torch.cuda.set_sync_debug_mode("default")
    env.close()


@cuda
def test_cuda_collector_and_ppo_iteration_stay_on_the_gpu():
    from torchrl.collectors import Collector

    from truckrl.env import TruckEnv
    from truckrl.rl.config import ModelConfig, PPOConfig
    from truckrl.rl.network import make_actor_critic
    from truckrl.rl.ppo import PPO

    env = TruckEnv(num_envs=128, device="cuda", seed=0)
    ac = make_actor_critic(ModelConfig(), 26, 16)
    ac.model.to("cuda")
    collector = Collector(env, ac.rollout_policy, frames_per_batch=128 * 16, total_frames=-1,
                          device="cuda", auto_register_policy_transforms=False)  # fmt: skip
    batch = next(iter(collector))
    assert all(t.device.type == "cuda" for t in batch.values(True, True))
    ppo = PPO(ac, PPOConfig(num_epochs=1, num_minibatches=2))
    metrics = ppo.update(batch)
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())
    for p in ac.model.parameters():
        assert p.device.type == "cuda"
        for s in ppo.optimizer.state[p].values():
            assert not torch.is_tensor(s) or s.device.type == "cuda" or s.dim() == 0
    collector.shutdown()
    env.close()


@cuda
def test_cuda_demonstrations_plan_and_clone_on_the_gpu():
    """experiment=gpu_demos' start: the planner plans on the GPU and the cloned actor stays there
    (ran on an H100 inside a whole run, docs/benchmarks.md, GPU)."""
    from truckrl.config.schemas import DemosConfig
    from truckrl.rl.config import ModelConfig
    from truckrl.rl.imitation import bootstrap
    from truckrl.rl.network import make_actor_critic
    from truckrl.tasks import EnvConfig

    ac = make_actor_critic(ModelConfig(), 26, 16)
    ac.model.to("cuda")
    dc = DemosConfig(episodes=4, difficulty=0.0, samples=48, iterations=3, compile=False, epochs=2)
    summary, samples = bootstrap(ac, EnvConfig(max_steps=120), dc, "cuda")
    assert summary["plans_kept"] >= 1 and samples.batch_size[0] > 0
    assert all(p.device.type == "cuda" for p in ac.model.parameters())
