"""``python -m truckrl.play`` and ``truckrl.viewer.runner``: keys, frame loop, policy, video, window.

Expected motion is hand-computed from the control law (``v_k = k * max_accel * dt`` under full
acceleration, ``steer_k = -k * max_steer_rate * dt`` under full right steer rate, set-points moving
by ``setpoint_rate * dt`` per step), not taken from the code under test.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from tests.conftest import TINY_TRAIN, compose_config, run_cli
from tests.reliability.harness import assert_one_line_error, run_main
from truckrl.cli import to_config
from truckrl.config.fields import ConfigError, build
from truckrl.config.schemas import PlayConfig
from truckrl.env import TruckEnv
from truckrl.play import build_runner, play
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.rl.policy import saved_config
from truckrl.sim.control import ControlConfig
from truckrl.tasks import EnvConfig
from truckrl.viewer.runner import LoopResult, Runner, run_loop
from truckrl.viz.keyboard import (
    Command,
    KeyboardConfig,
    KeyInput,
    KeyMapper,
    command_for,
    parse_key_script,
)

SMALL_VIEW = {"size_px": 96, "panel_px": 64}
DT = 0.1  # [s] paper


def drive(
    tmp_path: Path, script: str, env_cfg: EnvConfig | None = None, **options
) -> tuple[Runner, LoopResult, list]:
    """Play a key script headless; return the runner, the loop result and the state per frame."""
    keys = tmp_path / "keys.txt"
    keys.write_text(script)
    pc = PlayConfig(headless=True, actions=str(keys), view=SMALL_VIEW, env=env_cfg, **options)
    runner, inputs, _, _ = build_runner(pc)
    states: list = []
    result = run_loop(
        runner, inputs, episodes=1, sinks=(lambda r: states.append(r.env.get_state()[0]),)
    )
    return runner, result, states


# ---------------------------------------------------------------------------------- keyboard
def test_key_mapping_derivative_modes_command_full_scale_or_zero():
    m = KeyMapper(ControlConfig("accel", "rate"), KeyboardConfig(), DT)
    now = (0.3, -0.7)  # ignored by derivative modes
    assert m.action({"w"}, now) == (1.0, 0.0)
    assert m.action({"s", "a"}, now) == (-1.0, 1.0)
    assert m.action({"w", "d"}, now) == (1.0, -1.0)
    assert m.action(set(), now) == (0.0, 0.0)
    assert m.action({"w", "s", "a", "d"}, now) == (0.0, 0.0)  # opposite keys cancel
    assert m.action({"W", "x"}, now) == (1.0, 0.0)  # case-insensitive, other keys ignored


def test_key_mapping_setpoint_modes_ramp_hold_and_recentre():
    m = KeyMapper(ControlConfig("speed", "angle"), KeyboardConfig(1.0, 2.0), DT)
    assert m.action({"w"}, (-1.0, 0.0)) == pytest.approx((-0.9, 0.0))  # +1.0/s x 0.1 s
    assert m.action({"s", "a"}, (0.5, 0.2)) == pytest.approx((0.4, 0.3))
    assert m.action({"w", "d"}, (1.0, -1.0)) == pytest.approx((1.0, -1.0))  # clipped
    assert m.action(set(), (0.37, 0.5)) == pytest.approx((0.37, 0.3))  # hold speed; -2.0/s x 0.1
    assert m.action(set(), (0.0, -0.5)) == pytest.approx((0.0, -0.3))
    assert m.action(set(), (0.0, 0.1)) == pytest.approx((0.0, 0.0))  # no overshoot past centre


def test_command_keys():
    expected = {
        "r": Command.RESTART,
        "N": Command.NEW_SCENE,
        "p": Command.PAUSE,
        "space": Command.PAUSE,
        ".": Command.STEP,
        "+": Command.HARDER,
        "[+]": Command.HARDER,
        "-": Command.EASIER,
        "m": Command.TOGGLE_MODE,
        "q": Command.QUIT,
        "escape": Command.QUIT,
        "w": None,
        "x": None,
    }
    assert {k: command_for(k) for k in expected} == expected


def test_key_script_format_and_errors():
    frames = parse_key_script("# demo\nW 2\n!r !+   # presses\nwd\n- 2\n!q\n")
    assert frames == [
        KeyInput(frozenset("w")),
        KeyInput(frozenset("w")),
        KeyInput(frozenset("wd"), ("r", "+")),
        KeyInput(frozenset()),
        KeyInput(frozenset()),
        KeyInput(frozenset(), ("q",)),
    ]
    with pytest.raises(ConfigError, match="line 2.*WASD"):
        parse_key_script("W 3\nWX 2\n")
    with pytest.raises(ConfigError, match="line 1.*integer"):
        parse_key_script("W many\n")
    with pytest.raises(ConfigError, match="line 1.*command key"):
        parse_key_script("!z\n")


# ---------------------------------------------------------------------------------- frame loop
def test_w_accelerates_and_d_turns_clockwise(tmp_path):
    runner, result, states = drive(tmp_path, "W 10\nWD 6\n")
    assert result.steps == 16 and result.frames == 17
    p = states[0]["params"]
    a, rate, vmax = float(p["max_accel"]), float(p["max_steer_rate"]), float(p["max_speed"])
    speeds = [float(s["speed"]) for s in states]
    for k in range(17):  # W held every step: full acceleration
        assert speeds[k] == pytest.approx(min(k * a * DT, vmax), abs=1e-4)
    steers = [float(s["steer"]) for s in states[10:]]
    for j, steer in enumerate(steers):  # D held from step 11: steer right at the full rate
        assert steer == pytest.approx(-j * rate * DT, abs=1e-5)
    theta = [float(s["pose"][2]) for s in states[10:]]
    turn = [math.remainder(b - a_, 2 * math.pi) for a_, b in zip(theta, theta[1:], strict=False)]
    assert all(d < 0 for d in turn[1:]), turn  # clockwise: heading decreases
    assert turn[-1] < turn[1]  # and faster as the wheel turns further


def test_speed_angle_mode_ramps_holds_and_recentres(tmp_path):
    cfg = EnvConfig(control=ControlConfig("speed", "angle"))
    _, _, states = drive(tmp_path, "W 5\n- 3\nA 4\n- 2\n", cfg)
    p = states[0]["params"]
    vmax, smax = float(p["max_speed"]), float(p["max_steer"])
    v = [float(s["speed"]) for s in states]
    steer = [float(s["steer"]) / smax for s in states]
    # set-point: action -1 (0 m/s) + 0.1 per W step; action u -> speed (u + 1) / 2 * max_speed
    assert v[5] == pytest.approx(0.25 * vmax, rel=1e-4)
    assert v[8] == pytest.approx(0.25 * vmax, rel=1e-4)  # held with nothing pressed
    assert steer[12] == pytest.approx(0.4, abs=1e-5)  # +0.1 per A step
    assert steer[13] == pytest.approx(0.2, abs=1e-5) and steer[14] == pytest.approx(0.0, abs=1e-6)


def test_restart_key_replays_the_scene_and_new_scene_key_changes_it(tmp_path):
    _, _, states = drive(tmp_path, "W 8\n!r\n-\n!n\n-\n")
    start, after_restart, after_new = states[0], states[9], states[10]
    # at rest with nothing held (accel/rate: command 0), the restarted truck stays on its start
    assert torch.equal(after_restart["pose"], start["pose"])
    assert not torch.equal(states[8]["pose"], start["pose"])
    for k in ("goal", "segments", "mask"):
        assert torch.equal(after_restart[k], start[k]), k
    assert int(after_restart["step_count"]) == 1
    assert not torch.equal(after_new["goal"], start["goal"])
    # the restart drew nothing from the generator: the new scene is the env's second scene
    twin = TruckEnv(num_envs=1, seed=0)
    twin.reset()
    twin.reset()
    assert torch.equal(twin.get_state()[0]["goal"], after_new["goal"])


def test_pause_then_step_key_advances_exactly_one_frame(tmp_path):
    runner, result, states = drive(tmp_path, "W 5\n!p\nW 4\n!.\nW 3\n!p\nW 2\n")
    steps = [int(s["step_count"]) for s in states]
    assert result.steps == 5 + 1 + 2
    assert steps[-1] == 8
    assert runner.paused is False
    paused_at = steps.index(5)
    assert steps[paused_at : paused_at + 3] == [5, 5, 6]  # pause frame, then '.' steps once


def test_difficulty_keys_change_tolerance(tmp_path):
    runner, _, _ = drive(tmp_path, "!+ !+ !+\n-\n!-\n-\n")
    pos, ang = runner.env.tolerances()
    assert runner.env.get_difficulty() == 1.0
    assert float(pos[0]) == pytest.approx(30.0 / 2)  # paper: 30 m x 2^-d
    assert float(ang[0]) == pytest.approx(math.radians(60.0) / 2)


def test_record_writes_every_frame_shown(tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("W 6\nWA 3\n")
    video = tmp_path / "sub" / "run.mp4"
    pc = PlayConfig(headless=True, actions=str(keys), record=str(video), view=SMALL_VIEW)
    result = play(pc)
    assert result.frames == 10
    cap = cv2.VideoCapture(str(video))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    assert len(frames) == 10
    assert frames[0].shape == (96, 96 + 64, 3)
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(1 / DT)  # default: real time
    # the frames shown by the same run (same seed, same keys), collected here: the video holds
    # them in order, up to the codec's loss
    runner, inputs, _, _ = build_runner(pc)
    shown: list = []
    run_loop(runner, inputs, episodes=1, sinks=(lambda r: shown.append(r.frame.copy()),))
    assert len(shown) == 10
    # mean |error| of each video frame (BGR -> RGB) against each shown frame: the codec's loss
    # is about 3 levels; every video frame is nearest the shown frame of its own index
    err = np.array(
        [[np.abs(v[..., ::-1].astype(int) - w.astype(int)).mean() for w in shown] for v in frames]
    )
    assert (err.diagonal() < 4.0).all(), err.diagonal()
    assert (err.argmin(1) == np.arange(10)).all(), err.argmin(1)


def test_headless_without_input_drives_one_random_episode(tmp_path):
    env_cfg = EnvConfig(max_steps=12)
    strip = str(tmp_path / "s.png")
    pc = PlayConfig(headless=True, view=SMALL_VIEW, strip=strip, strip_height=32, env=env_cfg)
    result = play(pc)
    assert len(result.outcomes) == 1 and result.frames == result.steps + 1 <= 13
    strip = cv2.imread(str(tmp_path / "s.png"))
    assert strip.shape[0] == 32 and strip.shape[1] == 5 * 32 + 4 * 6  # 5 square tiles, 6 px gaps
    capped = play(PlayConfig(headless=True, view=SMALL_VIEW, max_frames=4, env=env_cfg))
    assert capped.frames == 4 and capped.steps == 3


def test_same_seed_same_scene_as_the_env_with_the_training_config_groups():
    cfg = compose_config("play", "seed=5", "control=speed_angle", "env.max_steps=50")
    pc = to_config(PlayConfig, cfg)
    env_cfg = pc.env
    assert (env_cfg.control.longitudinal, env_cfg.control.lateral) == ("speed", "angle")
    pc.env = dataclasses.replace(env_cfg, compile=True)
    runner, _, _, _ = build_runner(pc)
    assert runner.env.config.max_steps == 50 and runner.mode == "manual"
    assert runner.env.config.compile is False  # one truck: always eager
    ref = TruckEnv(num_envs=1, seed=5, config=env_cfg).reset()
    assert torch.equal(runner.first_observation["observation"], ref["observation"])
    assert torch.equal(runner.first_observation["lidar"], ref["lidar"])


# ---------------------------------------------------------------------------------- policy
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A checkpoint from the real training entry point with tiny settings."""
    d = tmp_path_factory.mktemp("run")
    proc = run_cli("train", *TINY_TRAIN, "total_frames=64", f"hydra.run.dir={d}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return d


def test_policy_plays_the_mean_action_in_the_seeded_scene(run_dir):
    pc = PlayConfig(
        headless=True, checkpoint=str(run_dir), seed=11, view=SMALL_VIEW, env=EnvConfig(max_steps=5)
    )  # env ignored: the checkpoint's
    runner, inputs, _, _ = build_runner(pc)
    assert runner.mode == "policy" and runner.env.config.max_steps == 200
    first = runner.first_observation
    state = load_checkpoint(run_dir)
    state["path"] = run_dir
    ref_cfg = build(EnvConfig, saved_config(state)["env"])
    ref_cfg.compile = False  # the viewer steps one truck eagerly
    ref = TruckEnv(num_envs=1, seed=11, config=ref_cfg).reset()
    assert torch.equal(first["observation"], ref["observation"])
    assert torch.equal(first["lidar"], ref["lidar"])

    ac = make_actor_critic(ModelConfig(), 26, state["num_beams"])  # the default run's 32
    ac.model.load_state_dict(state["model"])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = ac.actor(ref.select("observation", "lidar"))["loc"]
    result = run_loop(runner, inputs, max_frames=2)
    assert result.steps == 1
    assert torch.allclose(runner.last_action, expected, atol=1e-6)

    runner.command(Command.TOGGLE_MODE)
    assert runner.mode == "manual"


@pytest.mark.e2e
def test_policy_cli_records_video(run_dir, tmp_path):
    video = tmp_path / "policy.mp4"
    args = [f"checkpoint={run_dir}", "headless=true", "max_frames=6", f"record={video}"]
    args += ["view.size_px=64", "view.panel_px=0", f"hydra.run.dir={tmp_path}"]
    proc = run_cli("play", *args)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    cap = cv2.VideoCapture(str(video))
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == 6
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (64, 64)


@pytest.mark.parametrize("kind", ["missing", "corrupt"])
def test_bad_checkpoint_is_one_line_and_exit_code_2(kind, tmp_path, capsys):
    path = tmp_path / "nonexistent.pt"
    if kind == "corrupt":
        path = tmp_path / "last.pt"
        path.write_bytes(b"PK\x03\x04 definitely not a torch file")
    args = [f"checkpoint={path}", "headless=true", f"hydra.run.dir={tmp_path}"]
    r = run_main(capsys, "play", *args)
    assert_one_line_error(r, "not found" if kind == "missing" else "cannot read")


def test_bad_options_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match="on_done"):
        PlayConfig(on_done="later")
    with pytest.raises(ConfigError, match="view.size_px"):
        PlayConfig(view={"size_px": 5})
    with pytest.raises(ConfigError, match="not both"):
        PlayConfig(checkpoint="a", actions="b")
    with pytest.raises(ConfigError, match="actions file not found"):
        build_runner(PlayConfig(headless=True, actions=str(tmp_path / "nope.txt")))
    bad = tmp_path / "a.npy"
    np.save(bad, np.zeros((4, 3)))
    with pytest.raises(ConfigError, match=r"shape \[F >= 1, 2\]"):
        build_runner(PlayConfig(headless=True, actions=str(bad)))


def test_npy_actions_replay_until_the_array_ends(tmp_path):
    arr = tmp_path / "a.npy"
    np.save(arr, np.array([[1.0, 0.0]] * 4, dtype=np.float32))
    runner, inputs, _, _ = build_runner(
        PlayConfig(headless=True, actions=str(arr), view=SMALL_VIEW)
    )
    result = run_loop(runner, inputs)
    a = float(runner.env.get_state()[0]["params", "max_accel"])
    assert result.steps == 4 and runner.mode == "replay"
    assert float(runner.env.get_state()[0]["speed"]) == pytest.approx(4 * a * DT, rel=1e-5)


# ---------------------------------------------------------------------------------- window
def test_pygame_window_runs_with_posted_keys(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame = pytest.importorskip("pygame")
    from truckrl.viz.window import Window

    runner, _, _, _ = build_runner(PlayConfig(view=SMALL_VIEW))
    assert runner.mode == "manual"
    script = {
        2: (pygame.K_p, "p"),
        4: (pygame.K_PERIOD, "."),
        5: (pygame.K_EQUALS, "+"),
        7: (pygame.K_ESCAPE, "\x1b"),
    }
    calls = []

    def key_state():  # held keys; posts the next frame's key presses as real pygame events
        calls.append(1)
        if len(calls) in script:
            key, char = script[len(calls)]
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key, unicode=char, mod=0))
        return {"w"}

    window = Window(runner.frame.shape[1::-1], key_state=key_state)
    try:
        result = run_loop(runner, window, window=window, fps=1000.0)
        shown = pygame.surfarray.array3d(window.screen).swapaxes(0, 1)
    finally:
        window.close()
    # steps at polls 1, 2; paused at 3, 4; '.' steps once at 5; paused after; Esc at poll 8
    assert len(calls) == 8 and result.steps == 3
    assert runner.paused and runner.env.get_difficulty() == 0.5
    assert np.array_equal(shown, runner.frame)
    assert float(runner.env.get_state()[0]["speed"]) > 0


# ---------------------------------------------------------------------------------- reversing
REVERSE_TASK = {"name": "tests.tasks.reverse_reach_task"}


def _hud_text(runner: Runner) -> list[str]:
    return [x if isinstance(x, str) else x[0] for x in runner.hud(runner.env.get_state()[0])]


def _gear(runner: Runner) -> str:
    line = next(x for x in _hud_text(runner) if x.startswith("speed"))
    return line.split("gear")[1].strip()


def test_s_at_rest_reverses_and_w_brakes_then_drives_forward(tmp_path):
    # accel mode (default): full S = -max_accel every step, down to -max_reverse_speed; then
    # full W = +max_accel through 0 into forward driving
    runner, _, states = drive(tmp_path, "S 30\nW 30\n", EnvConfig(task=REVERSE_TASK), difficulty=5)
    p = states[0]["params"]
    a, vr, vmax = (float(p[k]) for k in ("max_accel", "max_reverse_speed", "max_speed"))
    v = [float(s["speed"]) for s in states]
    for k in range(31):
        assert v[k] == pytest.approx(max(-k * a * DT, -vr), abs=1e-4), k
    assert v[30] == pytest.approx(-vr, abs=1e-5)  # at the reverse limit, not below
    for j in range(31):
        assert v[30 + j] == pytest.approx(min(-vr + j * a * DT, vmax), abs=1e-4), j
    assert v[-1] > 0
    # backing: the rear axle moved against its heading while the speed was negative
    x0, x30 = states[0]["pose"], states[30]["pose"]
    heading = torch.stack((x0[2].cos(), x0[2].sin()))
    assert float(((x30[:2] - x0[:2]) * heading).sum()) < -1.0
    assert _gear(runner) == "D"
    hud = " ".join(_hud_text(runner))
    assert "brake, reverse" in hud


def test_gear_shows_r_while_reversing_and_n_at_rest(tmp_path):
    runner, _, _ = drive(tmp_path, "S 5\n", EnvConfig(task=REVERSE_TASK), difficulty=5)
    assert float(runner.env.get_state()[0]["speed"]) < 0 and _gear(runner) == "R"
    runner.restart()
    assert _gear(runner) == "N"


def test_speed_mode_setpoint_goes_below_zero_in_a_reversing_task(tmp_path):
    # speed mode maps [-1, 1] onto [-max_reverse_speed, max_speed]; S moves the set-point down
    # by setpoint_rate * dt = 0.1 action units per step, i.e. 0.05 (vmax + vr) m/s
    cfg = EnvConfig(control=ControlConfig("speed", "angle"), task=REVERSE_TASK)
    runner, _, states = drive(tmp_path, "S 40\n", cfg, difficulty=5)
    p = states[0]["params"]
    vr, vmax = float(p["max_reverse_speed"]), float(p["max_speed"])
    v = [float(s["speed"]) for s in states]
    for k in range(41):
        assert v[k] == pytest.approx(max(-k * 0.05 * (vmax + vr), -vr), abs=1e-4), k
    assert v[-1] == pytest.approx(-vr, abs=1e-5) and _gear(runner) == "R"


@pytest.mark.parametrize("control", [("accel", "rate"), ("speed", "angle")])
def test_forward_task_s_at_rest_stays_at_zero(tmp_path, control):
    runner, _, states = drive(
        tmp_path, "S 5\nW 3\nS 10\n", EnvConfig(control=ControlConfig(*control))
    )
    v = [float(s["speed"]) for s in states]
    assert min(v) == 0.0 and v[5] == 0.0 and v[-1] == 0.0 and max(v) > 0
    assert _gear(runner) == "N"
    assert "brake, reverse" not in " ".join(_hud_text(runner))


def test_pygame_window_reverses_with_s_held(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame = pytest.importorskip("pygame")
    from truckrl.viz.window import Window

    pc = PlayConfig(view=SMALL_VIEW, env=EnvConfig(task=REVERSE_TASK), difficulty=5)
    runner, _, _, _ = build_runner(pc)
    calls = []

    def key_state():  # S held; Esc posted at poll 7 is read at poll 8
        calls.append(1)
        if len(calls) == 7:
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE, mod=0))
        return {"s"}

    window = Window(runner.frame.shape[1::-1], key_state=key_state)
    try:
        result = run_loop(runner, window, window=window, fps=1000.0)
    finally:
        window.close()
    assert len(calls) == 8 and result.steps == 7
    s = runner.env.get_state()[0]
    a, vr = float(s["params", "max_accel"]), float(s["params", "max_reverse_speed"])
    assert float(s["speed"]) == pytest.approx(max(-7 * a * DT, -vr), abs=1e-4)
    assert _gear(runner) == "R"


# ---------------------------------------------------------------------------------- policy=SPEC
PLAY_DRIVERS = """
import torch

def make(env_config):  # obs -> action: half throttle, steer against the lateral goal offset
    return lambda observation, lidar: torch.stack(
        [torch.full_like(observation[:, 0], 0.5), (-0.4 * observation[:, 1]).clamp(-1, 1)], -1
    )
"""


@pytest.mark.parametrize("scheme", ["onnx", "module", "pretrained", "planner"])
def test_play_drives_every_policy_scheme(scheme, tmp_path, monkeypatch):
    """``play policy=SPEC`` headless: the first step applies the policy's action on the first
    observation (computed here without the viewer), in the env the spec says."""
    import sys

    import truckrl.play as play_module
    from tests.test_policy_specs import card_for, linear_onnx

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    small = EnvConfig(max_steps=30)
    env_cfg, difficulty = small, None
    if scheme == "onnx":
        a, b = linear_onnx(tmp_path / "p.onnx", card=card_for(small, 2.5))
        spec, difficulty = f"onnx:{tmp_path / 'p.onnx'}", 2.5

        def oracle(first):
            return first["observation"].numpy() @ a + first["lidar"].numpy() @ b

    elif scheme == "module":
        monkeypatch.chdir(tmp_path)
        (tmp_path / "play_drivers.py").write_text(PLAY_DRIVERS)
        monkeypatch.delitem(sys.modules, "play_drivers", raising=False)
        spec, env_cfg = "play_drivers:make", EnvConfig(max_steps=30, task={"name": "dock"})

        def oracle(first):
            lateral = (-0.4 * first["observation"][:, 1]).clamp(-1, 1)
            return np.array([[0.5, float(lateral[0])]], np.float32)

    elif scheme == "pretrained":
        from truckrl.rl.policy import load_policy

        shipped = load_policy("pretrained")
        spec, env_cfg, difficulty = "pretrained", shipped.env_config, shipped.difficulty

        def oracle(first):
            with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
                return shipped.actor(first.clone())["action"].numpy()

    else:
        from truckrl.planning import PlannerConfig, plan_states

        tiny = PlannerConfig(compile=False, samples=8, iterations=1, attempts=1)
        monkeypatch.setattr(play_module, "planner_config", lambda: tiny)
        spec, difficulty = "planner", 1.0

        def oracle(first):  # the plan's first 16 actions (its steering turns at step 13)
            env = TruckEnv(num_envs=1, seed=4, config=small)
            env.reset()
            res, _, _ = plan_states(small, env.get_state(), 1.0, tiny)
            return res["actions"][0, :16].numpy()

    pc = PlayConfig(headless=True, policy=spec, seed=4, view=SMALL_VIEW, env=env_cfg)
    if scheme == "planner":
        pc.difficulty = 1.0
    runner, inputs, _, what = build_runner(pc)
    assert runner.mode == "policy" and runner.env.config == dataclasses.replace(
        env_cfg, compile=False
    )
    if difficulty is not None:
        assert runner.env.get_difficulty() == difficulty
    steps = 16 if scheme == "planner" else 1  # the planner replays its plan: check a stretch
    actions: list = []
    sink = (lambda r: actions.append(r.last_action),)
    result = run_loop(runner, inputs, max_frames=steps + 1, episodes=1, sinks=sink)
    assert result.steps == steps  # an ended episode stays (episodes=1): one scene throughout
    expected = oracle(runner.first_observation)
    got = torch.cat(actions[1:]).numpy()  # the first frame is before any step
    np.testing.assert_allclose(got, expected, atol=1e-5, rtol=0)


def test_play_policy_spec_on_the_command_line(tmp_path, monkeypatch, capsys):
    from tests.reliability.harness import run_main
    from tests.test_policy_specs import card_for, linear_onnx

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    linear_onnx(tmp_path / "p.onnx", card=card_for(EnvConfig(max_steps=30), 0.0))
    view = ["view.size_px=64", "view.panel_px=0", f"hydra.run.dir={tmp_path}"]
    r = run_main(capsys, "play", f"policy=onnx:{tmp_path / 'p.onnx'}", "headless=true", *view)
    assert r.code == 0, r.err
    assert f"play: policy {tmp_path / 'p.onnx'} (onnx:" in r.out and "episode 1:" in r.out
    r = run_main(capsys, "play", "policy=absent_play_mod:make", "headless=true", *view)
    assert r.code == 2 and len(r.err.strip().splitlines()) == 1
    assert r.err.startswith("error: policy = 'absent_play_mod:make': module 'absent_play_mod'")
    r = run_main(capsys, "play", "policy=planner", "actions=keys.txt", "headless=true", *view)
    assert r.code == 2 and "give policy (or checkpoint) or actions, not both" in r.err


# ---------------------------------------------------------------------------------- networks
#: A task whose scenes are larger than the view: the camera follows the truck (the route
#: through a road network's junctions, hundreds of metres long).
FAR_TASK = {"name": "network"}


def test_keyboard_drives_a_network_in_the_window_with_the_camera_on_the_truck(monkeypatch):
    """``play task=network`` in a pygame window (dummy video driver): W held drives the truck
    and every frame shows the tractor at the view's centre (the camera follows it)."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame = pytest.importorskip("pygame")
    from truckrl.viz.window import Window

    view = {"size_px": 160, "panel_px": 0}
    pc = PlayConfig(view=view, env=EnvConfig(task=FAR_TASK), difficulty=6.0, seed=3)
    runner, _, _, _ = build_runner(pc)
    assert runner.mode == "manual" and runner._camera is None
    calls, centres = [], []

    def key_state():
        calls.append(1)
        if len(calls) == 8:
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_q, unicode="q"))
        return {"w"}

    def tractor_rows_cols(frame):
        r, g, b = (frame[..., i].astype(int) for i in range(3))
        return np.nonzero((b - r > 40) & (b - g > 25))  # the tractor's blues

    window = Window(runner.frame.shape[1::-1], key_state=key_state)
    try:
        result = run_loop(
            runner, window, window=window, fps=1000.0,
            sinks=(lambda r: centres.append(tractor_rows_cols(r.view_image)),),
        )  # fmt: skip
        shown = pygame.surfarray.array3d(window.screen).swapaxes(0, 1)
    finally:
        window.close()
    assert result.steps == 8 and np.array_equal(shown, runner.frame)  # Q read at poll 9
    assert float(runner.env.get_state()[0]["speed"]) > 0
    # the rear axle at the centre, the tractor's centre < 3 m ahead of it: 0.8125 m/px
    # (half extent: 50 m LiDAR + 15 m margin over 80 px)
    for rows, cols in centres:
        assert len(rows) > 10
        assert math.hypot(rows.mean() - 79.5, cols.mean() - 79.5) < 3.0 / 0.8125 + 1.0


@pytest.mark.slow
def test_a_network_checkpoint_plays_and_records(tmp_path):
    """A checkpoint of the network task (tiny training run) drives ``play`` headless into an
    mp4 of every frame."""
    d = tmp_path / "run"
    proc = run_cli("train", *TINY_TRAIN, "total_frames=64", "task=network", f"hydra.run.dir={d}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    video = tmp_path / "drive.mp4"
    args = [f"checkpoint={d}", "headless=true", "max_frames=6", f"record={video}"]
    args += ["view.size_px=96", "view.panel_px=0", f"hydra.run.dir={tmp_path}"]
    proc = run_cli("play", *args)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    cap = cv2.VideoCapture(str(video))
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == 6
    frames = [cap.read()[1][..., ::-1] for _ in range(6)]
    for f in frames:  # the tractor near the centre of every frame
        r, g, b = (f[..., i].astype(int) for i in range(3))
        rows, cols = np.nonzero((b - r > 40) & (b - g > 25))
        assert len(rows) > 5 and math.hypot(rows.mean() - 47.5, cols.mean() - 47.5) < 8
