"""The viewer's Runner and frame loop: waiting for the first key, the outcome banner hold, the
key help, a stable panel and a camera that shows the start truck and the goal."""

from __future__ import annotations

import numpy as np
import pytest

from truckrl.env import TruckEnv
from truckrl.sim.vehicle import truck_corners
from truckrl.tasks import EnvConfig
from truckrl.viewer.runner import (
    KeyboardSource,
    PolicySource,
    RandomSource,
    Runner,
    ViewConfig,
    run_loop,
)
from truckrl.viz.draw import make_view, world_to_pixel
from truckrl.viz.keyboard import KeyboardConfig, KeyInput

SMALL = ViewConfig(size_px=96, panel_px=64)


def manual_runner(max_steps: int = 200, **kwargs) -> Runner:
    env = TruckEnv(num_envs=1, seed=0, config=EnvConfig(max_steps=max_steps))
    return Runner(env, {"manual": KeyboardSource(env, KeyboardConfig())}, "manual", SMALL, **kwargs)


class FakeWindow:
    """A window that replays KeyInputs (then quits) and keeps what it showed."""

    def __init__(self, script: list[KeyInput]) -> None:
        self.script, self.shown = list(script), []

    def poll(self) -> KeyInput:
        return self.script.pop(0) if self.script else KeyInput(quit=True)

    def show(self, frame: np.ndarray) -> None:
        self.shown.append(frame)

    def tick(self, fps: float) -> None:
        pass


def step_count(runner: Runner) -> int:
    return int(runner.env.get_state()[0]["step_count"])


def test_waiting_runner_steps_only_after_a_drive_key():
    runner = manual_runner(wait_for_key=True)
    assert runner.waiting and "WAITING" in runner.hud(runner.env.get_state()[0])[0][0]
    banner = runner.view_image.copy()
    assert not runner.step(frozenset()) and step_count(runner) == 0  # no clock before a key
    assert runner.step(frozenset("w")) and step_count(runner) == 1
    assert not runner.waiting
    assert not np.array_equal(banner, runner.view_image)  # the hint banner is gone


def test_pause_key_also_starts_a_waiting_episode():
    from truckrl.viz.keyboard import Command

    runner = manual_runner(wait_for_key=True)
    runner.command(Command.PAUSE)
    assert not runner.waiting and not runner.paused
    assert runner.step(frozenset())


def test_headless_loop_never_waits():
    runner = manual_runner()
    assert not runner.waiting
    script = iter([KeyInput()] * 3)
    result = run_loop(runner, type("Keys", (), {"poll": lambda self: next(script, None)})())
    assert result.steps == 3 and step_count(runner) == 3


def test_window_waits_for_the_first_key_and_holds_the_outcome_until_a_key():
    runner = manual_runner(max_steps=3)
    idle = KeyInput()
    script = [idle] * 4 + [KeyInput(frozenset("w"))] * 3 + [idle] * 5 + [KeyInput(pressed=("x",))]
    script += [idle] * 2
    window = FakeWindow(script)
    result = run_loop(runner, window, window=window, fps=1000.0, done_hold_s=3600.0)
    # 4 idle polls: nothing; W x 3: the 3-step episode times out; then the banner stays through
    # 5 idle polls, the key press starts a new scene, which waits again (2 idle polls)
    assert result.steps == 3 and result.outcomes == ["TIMEOUT"]
    assert runner.episodes_done == 1 and runner.waiting and step_count(runner) == 0
    assert len(window.shown) == len(script)
    held = window.shown[7:12]  # the frames shown while the outcome banner holds
    assert all(np.array_equal(f, held[0]) for f in held)
    assert not np.array_equal(window.shown[12], held[0])


def test_outcome_banner_moves_on_after_done_hold_s():
    runner = manual_runner(max_steps=2)
    window = FakeWindow([KeyInput(frozenset("w"))] * 2 + [KeyInput()] * 3)
    run_loop(runner, window, window=window, fps=1000.0, done_hold_s=0.0)
    assert runner.episodes_done == 1 and not runner.ended  # a new scene at once


def test_key_help_lists_m_only_with_a_policy():
    runner = manual_runner()
    lines = [x if isinstance(x, str) else x[0] for x in runner.hud(runner.env.get_state()[0])]
    assert any(x.startswith("W / S") for x in lines) and not any(x.startswith("M\t") for x in lines)
    env = TruckEnv(num_envs=1, seed=0)
    sources = {"manual": KeyboardSource(env, KeyboardConfig()), "policy": RandomSource(0)}
    both = Runner(env, sources, "policy", SMALL)
    lines = [x if isinstance(x, str) else x[0] for x in both.hud(env.get_state()[0])]
    assert any(x.startswith("M\t") for x in lines)
    video = Runner(TruckEnv(num_envs=1, seed=0), {"policy": RandomSource(0)}, "policy", SMALL)
    lines = [x if isinstance(x, str) else x[0] for x in video.hud(video.env.get_state()[0])]
    assert not any("\t" in x for x in lines)  # no keyboard: no key help (training videos)


def test_panel_keeps_its_layout_at_the_first_step():
    runner = manual_runner()
    before = runner.hud(runner.env.get_state()[0])
    runner.step(frozenset("w"))
    after = runner.hud(runner.env.get_state()[0])
    assert len(before) == len(after)
    label = [(x if isinstance(x, str) else x[0]).split()[0] if x else "" for x in before]
    assert label == [(x if isinstance(x, str) else x[0]).split()[0] if x else "" for x in after]


@pytest.mark.parametrize("seed", range(6))
def test_fixed_camera_shows_the_start_truck_and_the_goal(seed):
    env = TruckEnv(num_envs=1, seed=seed)
    runner = Runner(env, {"policy": PolicySource(lambda td: td)}, "policy", ViewConfig())
    cam = runner._camera
    view = make_view(runner.view.size_px, cam["center"], view_half_extent=cam["view_half_extent"])
    s = env.get_state()
    tractor, trailer, _ = truck_corners(s["pose"], s["params"])
    pts = np.concatenate([tractor[0].numpy(), trailer[0].numpy(), s["goal"][0, None, :2].numpy()])
    px = world_to_pixel(pts, view)
    assert (px >= 0).all() and (px <= runner.view.size_px - 1).all()
