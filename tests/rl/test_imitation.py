"""Behaviour cloning from planner demonstrations: replayed samples, the fit, and the
``python -m truckrl.tools.imitate`` checkpoint that ``train resume=`` continues."""

from __future__ import annotations

import json

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import TINY_BATCH, TINY_TRAIN, run_cli
from tests.rl.test_planner import ENV, FAST, straight_scene
from truckrl import plan as plan_cli
from truckrl.env import TruckEnv
from truckrl.planning import plan_states
from truckrl.rl.imitation import (
    SAMPLES_NAME,
    behaviour_clone,
    bootstrap,
    demonstrations,
    load_samples,
    set_action_std,
)
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.rl.policy import load_policy
from truckrl.tools import imitate as imitate_cli


@pytest.fixture(scope="module")
def solved():
    """The straight scene and a planner sequence that solves it at difficulty 2."""
    state = straight_scene()
    res, _, _ = plan_states(ENV, state, 2.0, FAST)
    assert bool(res["success"][0])
    n = int(res["length"][0])
    return state, res["actions"][0, :n].tolist()


def test_samples_are_what_the_policy_sees_before_each_action(solved):
    state, actions = solved
    stalled = [[-1.0, 0.0]] * 30  # stands still: a timeout of this 30-step sequence
    both = torch.cat((state, state))
    samples, kept = demonstrations(ENV, both, [actions, stalled], 2.0)
    assert kept == 1 and samples.numel() == len(actions)  # the stalled one is dropped
    env = TruckEnv(num_envs=1, config=ENV, seed=0)
    env.set_difficulty(2.0)
    td = env.set_state(state.clone())
    for t in (0, 1, len(actions) - 1):
        if t:
            td = env.set_state(state.clone())
            for a in actions[:t]:
                td = env.step(td.set("action", torch.tensor([a])))["next"]
        assert torch.equal(samples["observation"][t], td["observation"][0])
        assert torch.equal(samples["lidar"][t], td["lidar"][0])
        assert samples["action"][t].tolist() == pytest.approx(actions[t])


def test_cloning_fits_the_mean_and_leaves_std_and_critic(solved):
    state, actions = solved
    samples, _ = demonstrations(ENV, state, [actions], 2.0)
    torch.manual_seed(0)
    ac = make_actor_critic(ModelConfig(), samples["observation"].shape[1], 16)
    log_std = ac.gaussian.log_std.detach().clone()
    value = [p.detach().clone() for p in ac.value_head.parameters()]
    losses = behaviour_clone(ac, samples, epochs=40, lr=3e-3, batch_size=32)
    assert losses[-1] < 0.3 * losses[0]
    assert torch.equal(ac.gaussian.log_std, log_std)
    assert all(torch.equal(a, b) for a, b in zip(value, ac.value_head.parameters(), strict=True))
    set_action_std(ac, 0.2)
    assert torch.allclose(ac.action_std(), torch.full((2,), 0.2))


def _small_plan(tmp_path, capsys):
    """A plan file of 3 scenes at difficulty 0 (40-step episodes), written by the plan CLI in
    process (its CLI has a subprocess test of its own); imitate and train run as users do."""
    plan_json = tmp_path / "plan.json"
    threads = torch.get_num_threads()
    try:
        code = plan_cli.main([
            "episodes=3", "difficulty=0", "planner.compile=false", "planner.samples=32",
            "planner.iterations=2", "quiet=true", "env.max_steps=40", f"out={plan_json}",
        ])  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    assert code == 0, capsys.readouterr().err
    return plan_json


@pytest.mark.e2e
def test_imitate_writes_a_checkpoint_that_train_resumes(tmp_path, capsys):
    plan_json = _small_plan(tmp_path, capsys)
    assert any(e["success"] for e in json.loads(plan_json.read_text())["per_episode"])
    out = tmp_path / "bc"
    # with the cloning term on: the samples go beside the checkpoint, and the resume uses them
    tiny = [f"train.{o}" for o in TINY_TRAIN if not o.startswith("demos.bc_coeff")]
    tiny += ["train.env.max_steps=40", "train.demos.bc_coeff=1"]
    proc = run_cli("tools.imitate", f"plan={plan_json}", *tiny, "epochs=3", f"out={out}")
    assert proc.returncode == 0, proc.stderr
    assert f"train: truckrl train resume={out}" in proc.stdout
    policy = load_policy(out)
    assert policy.counters["frames"] == 0 and policy.difficulty == 0.0
    kept = int(proc.stdout.split(" samples")[0].rsplit(" ", 1)[-1])
    samples = load_samples(out / SAMPLES_NAME)
    assert samples.numel() == kept > 0
    # planned with the plan CLI's env (the paper's 16 beams), replayed with the run's 32
    assert json.loads(plan_json.read_text())["env"]["lidar"]["num_beams"] == 16
    assert samples["lidar"].shape[1] == 32 and policy.env_config.lidar.num_beams == 32
    proc = run_cli("train", f"resume={out}", f"total_frames={TINY_BATCH}")
    assert proc.returncode == 0, proc.stderr
    assert load_policy(out).counters["frames"] == TINY_BATCH
    acc = EventAccumulator(str(out / "tb"))
    acc.Reload()
    assert acc.Scalars("loss/bc")[0].value > 0
    # a plan made with other env settings is refused in one line
    capsys.readouterr()
    train = [f"train.{o}" for o in TINY_TRAIN]
    err = _exit_2(capsys, f"plan={plan_json}", *train, f"out={tmp_path / 'x'}")
    assert len(err.strip().splitlines()) == 1
    assert err.startswith("error: plan ") and "(env.max_steps)" in err
    assert not (tmp_path / "x").exists()


def _exit_2(capsys, *argv: str) -> str:
    """``truckrl tools imitate argv`` in process: it must exit 2 (or return it); its stderr."""
    try:
        code = imitate_cli.main(list(argv))
    except SystemExit as exit_:
        code = exit_.code
    assert code == 2
    return capsys.readouterr().err


def test_bad_options_are_one_line(capsys):
    assert _exit_2(capsys, "plan=nowhere.json").startswith("error: plan nowhere.json")
    err = _exit_2(capsys, "plan=nowhere.json", "std=0")
    assert err.startswith("error: ") and "std" in err and len(err.strip().splitlines()) == 1


def test_samples_file_round_trips_and_a_bad_one_is_one_line(tmp_path):
    from tensordict import TensorDict

    from truckrl.rl.imitation import save_samples

    g = torch.Generator().manual_seed(0)
    samples = TensorDict(
        {"observation": torch.randn(5, 26, generator=g), "lidar": torch.rand(5, 16, generator=g),
         "action": torch.rand(5, 2, generator=g) * 2 - 1},
        [5],
    )  # fmt: skip
    path = save_samples(tmp_path / SAMPLES_NAME, samples)
    back = load_samples(path)
    assert back.batch_size == torch.Size([5])
    assert all(torch.equal(back[k], samples[k]) for k in ("observation", "lidar", "action"))
    assert not list(tmp_path.glob(".*"))  # written atomically: no temp file left
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a torch file")
    for p, text in ((bad, "is not a demonstrations file"), (tmp_path / "no.pt", "does not exist")):
        with pytest.raises(ValueError, match=text) as e:
            load_samples(p)
        assert str(p) in str(e.value) and len(str(e.value).splitlines()) == 1


def test_bootstrap_plans_on_demos_device_else_on_the_runs(monkeypatch):
    """``demos.device`` moves the planner (``cpu``: a GPU run planning on the host's cores);
    unset, it plans where the run is."""
    import truckrl.planning as planner
    from truckrl.config.schemas import DemosConfig

    seen = []

    def start_states(env_cfg, episodes, seed, device, difficulty=None):
        seen.append(str(device))
        raise RuntimeError("planned")  # where the planner runs is all this test needs

    monkeypatch.setattr(planner, "held_out_states", start_states)
    for dc, run_device in ((DemosConfig(episodes=2, device="cpu"), "meta"),
                           (DemosConfig(episodes=2), "meta")):  # fmt: skip
        with pytest.raises(RuntimeError, match="planned"):
            bootstrap(None, ENV, dc, run_device)
    assert seen == ["cpu", "meta"]


def test_plan_demos_takes_the_successful_episodes_that_hold_a_sequence():
    from truckrl.rl.imitation import plan_demos

    plan = {"per_episode": [
        {"scene_index": 0, "success": True, "actions": [[0.5, 0.0]]},
        {"scene_index": 3, "success": True},  # skip_solved: the policy's own, not written
        {"scene_index": 4, "success": False, "actions": [[1.0, 1.0]]},
        {"scene_index": 7, "success": True, "actions": [[0.1, -0.2], [0.0, 0.0]]},
    ]}  # fmt: skip
    assert plan_demos(plan) == ([0, 7], [[[0.5, 0.0]], [[0.1, -0.2], [0.0, 0.0]]])


def test_imitate_init_clones_into_a_checkpoints_weights(tmp_path, capsys, tiny_checkpoint):
    from truckrl.rl.checkpoint import load_training_state

    run, _, _ = tiny_checkpoint
    plan_json = _small_plan(tmp_path, capsys)
    threads = torch.get_num_threads()
    start = load_training_state(run)["model"]
    train = [f"train.{o}" for o in TINY_TRAIN] + ["train.env.max_steps=40", "train.seed=1"]
    weights = {}
    for name, extra in (
        ("init", [f"init={run}", "std=null", "epochs=1", "lr=0.0000001"]),
        ("kept", [f"init={run}", "std=null", "epochs=0"]),
        ("fresh", ["epochs=1", "lr=0.0000001"]),
    ):
        out = tmp_path / name
        args = [f"plan={plan_json}", *train, f"out={out}", *extra]
        try:
            assert imitate_cli.main(args) == 0, capsys.readouterr().err
        finally:
            torch.set_num_threads(threads)
        weights[name] = load_training_state(out)["model"]
    # one epoch at lr 1e-7 moves no weight by 1e-5: the clone starts from the checkpoint's
    # weights, log-std included (std=null keeps it); a fresh start (train.seed=1) is elsewhere
    for k, v in start.items():
        assert torch.allclose(weights["init"][k], v, atol=1e-5), k
        assert torch.equal(weights["kept"][k], v), k  # epochs=0: the weights as they are
    assert any(not torch.allclose(weights["fresh"][k], v, atol=1e-3) for k, v in start.items())
    assert "epochs = 0 needs init=" in _exit_2(capsys, f"plan={plan_json}", "epochs=0")
    err = _exit_2(capsys, f"plan={plan_json}", *train, f"init={tmp_path / 'none'}",
                  f"out={tmp_path / 'x'}")  # fmt: skip
    assert err.startswith("error: init = ") and len(err.strip().splitlines()) == 1


def test_executed_cloning_error_is_the_clamped_means_with_a_straight_through_gradient():
    """``action_mse(..., executed=True)``: hand-computed values. A mean of 2.5 against a
    demonstrated 1.0 costs 0 (the env executes 1.0 either way); against 0.3 it costs (1 - 0.3)^2
    and its gradient pulls it down as if unclamped; inside the bound both errors agree."""
    from types import SimpleNamespace

    from tensordict import TensorDict

    from truckrl.rl.imitation import action_mse

    loc = torch.tensor([[2.5, 0.2], [2.5, -3.0]], requires_grad=True)
    ac = SimpleNamespace(actor=SimpleNamespace(get_dist_params=lambda td: {"loc": loc}))
    batch = TensorDict(
        {"observation": torch.zeros(2, 1), "lidar": torch.zeros(2, 1),
         "action": torch.tensor([[1.0, 0.0], [0.3, -1.0]])},
        [2],
    )  # fmt: skip
    executed = action_mse(ac, batch, executed=True)
    assert executed.item() == pytest.approx((0.0 + 0.2**2 + 0.7**2 + 0.0) / 4)
    (grad,) = torch.autograd.grad(executed, loc)
    assert torch.allclose(grad, torch.tensor([[0.0, 2 * 0.2 / 4], [2 * 0.7 / 4, 0.0]]))
    plain = action_mse(ac, batch)
    assert plain.item() == pytest.approx((1.5**2 + 0.2**2 + 2.2**2 + 2.0**2) / 4)


def test_imitate_rebuilds_the_scenes_at_the_plans_difficulty(monkeypatch):
    """A task with a start curriculum (uturn) places its starts by the difficulty: imitate must
    rebuild a plan's scenes at the plan's difficulty, or no replay starts where the plan did."""
    import truckrl.planning as planning
    from truckrl.config.schemas import TrainConfig
    from truckrl.planning import held_out_states

    env = {"task": {"name": "uturn"}, "compile": False}
    at = {d: held_out_states(env, 2, 5, difficulty=d)["pose"] for d in (0.0, 6.0)}
    assert not torch.equal(at[0.0], at[6.0])  # the precondition: the starts move with it
    seen = []

    def start_states(env_cfg, episodes, seed, device="cpu", difficulty=None):
        seen.append(difficulty)
        raise RuntimeError("rebuilt")

    monkeypatch.setattr(planning, "held_out_states", start_states)
    plan = {"per_episode": [{"scene_index": 1, "success": True, "actions": [[0.0, 0.0]]}]}
    meta = {"episodes": 2, "seed": 5, "difficulty": 6.0}
    args = imitate_cli.ImitateConfig(plan="plan.json")
    with pytest.raises(RuntimeError, match="rebuilt"):
        imitate_cli._clone(args, TrainConfig(), plan, meta)
    assert seen == [6.0]
