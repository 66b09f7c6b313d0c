"""The viewer's frame loop: one truck driven by interchangeable action sources.

Paper, "Control abstractions": a single runner drives the environment from a learned policy or
from keyboard input, through the identical frame loop, renderer and safety clamps. Here an
*action source* maps ``(observation td, held keys)`` to the env action ``[1, 2]``:
:class:`KeyboardSource` (held keys through :class:`truckrl.viz.keyboard.KeyMapper`),
:class:`PolicySource` (a policy's mean action), :class:`ArraySource` (a recorded action array) and
:class:`RandomSource`. :class:`Runner` holds one ``TruckEnv`` (the training env: its ``[-1, 1]``
action clamp and non-finite guard apply to every source), the viewer commands (restart, new scene,
pause, single step, difficulty, mode) and the rendered frame; :func:`run_loop` is the one loop
that polls an input (a window, a key script, or nothing), steps, and shows/records frames.
Frames are drawn by :func:`truckrl.viz.video.render_frame` from a snapshot of the episode
(:meth:`Runner.frame_state`); training videos (:func:`truckrl.rl.logger.record_episode`) roll out
the env themselves and draw through the same function: one renderer for the viewer and the
videos.

In a window, a keyboard-driven episode waits for the first drive key (the episode clock and its
step limit start then), and a finished episode keeps its outcome banner until a key is pressed or
``done_hold_s`` passes. Headless runs (scripts, tests, recordings) never wait.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.config.fields import check_choice
from truckrl.env import TruckEnv
from truckrl.sim.control import ControlConfig, commanded
from truckrl.tasks import MAX_DIFFICULTY, OUTCOMES
from truckrl.viz.config import ViewConfig
from truckrl.viz.keyboard import (
    DRIVE_KEYS,
    Command,
    KeyboardConfig,
    KeyInput,
    KeyMapper,
    command_for,
    key_help,
)
from truckrl.viz.panel import Line
from truckrl.viz.video import (
    FrameState,
    fixed_camera,
    frame_strip,
    hud_lines,
    render_frame,
)

#: An action source: (current observation td ``[1]``, held drive keys) -> action ``[1, 2]``.
ActionSource = Callable[[TensorDictBase, frozenset[str]], Tensor]


class EndOfInput(Exception):
    """An action source or input script has nothing more to play."""


# ---------------------------------------------------------------------------------- sources
class PolicySource:
    """The policy's mean action (deterministic playback)."""

    def __init__(self, actor) -> None:
        self.actor = actor

    @torch.no_grad()
    def __call__(self, td: TensorDictBase, held: frozenset[str]) -> Tensor:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return self.actor(td.select("observation", "lidar"))["action"]


def commanded_values(state: TensorDictBase, control: ControlConfig, speed_floor: float):
    """The commanded quantities' present values on the action scale ``(u_lon, u_lat)``.

    Inverse of the control's affine map (``u * max_q``; speed: ``[-1, 1] -> [speed_floor,
    max_speed]``) applied to the truck's current speed/accel/jerk and steer/rate/accel.

    Args:
        state: one truck's state (scalar entries).
        speed_floor: the truck's lower speed bound [m/s], ``task.control.speed_floor(params)``:
            ``min_speed`` (0) for a forward-only task, ``-max_reverse_speed`` for one that
            reverses.
    """
    p = state["params"]
    (lon_key, lon_limit), (lat_key, lat_limit) = commanded(control.longitudinal, control.lateral)
    if lon_key == "speed":
        span = float(p[lon_limit]) - speed_floor
        u_lon = 2.0 * (float(state[lon_key]) - speed_floor) / span - 1.0
    else:
        u_lon = float(state[lon_key]) / float(p[lon_limit])
    u_lat = float(state[lat_key]) / float(p[lat_limit])
    return u_lon, u_lat


class KeyboardSource:
    """Held keys -> action through :class:`KeyMapper` (set-points read from the truck's state).

    In a task that reverses, S keeps braking below 0 into reverse (the control's speed floor is
    the truck's ``-max_reverse_speed``; :mod:`truckrl.viz.keyboard`).
    """

    def __init__(self, env: TruckEnv, cfg: KeyboardConfig) -> None:
        self.env = env
        self.mapper = KeyMapper(env.config.control, cfg, env.config.dt)

    def __call__(self, td: TensorDictBase, held: frozenset[str]) -> Tensor:
        cfg = self.env.config
        s = self.env.get_state()[0]
        floor = float(self.env.task.control.speed_floor(s["params"]))
        current = commanded_values(s, cfg.control, floor)
        action = self.mapper.action(held, current)
        return torch.tensor([action], dtype=torch.float32, device=self.env.device)


class ArraySource:
    """Replays an ``[F, 2]`` action array, one row per step; :class:`EndOfInput` after the last."""

    def __init__(self, actions: np.ndarray, device: str | torch.device = "cpu") -> None:
        self.actions = torch.as_tensor(actions, dtype=torch.float32, device=device)
        self._next = 0

    def __call__(self, td: TensorDictBase, held: frozenset[str]) -> Tensor:
        if self._next >= len(self.actions):
            raise EndOfInput
        self._next += 1
        return self.actions[self._next - 1 : self._next]


class RandomSource:
    """Uniform random actions in ``[-1, 1]`` from a seeded generator."""

    def __init__(self, seed: int, device: str | torch.device = "cpu") -> None:
        self.device = torch.device(device)
        self.rng = torch.Generator(device=self.device).manual_seed(seed)

    def __call__(self, td: TensorDictBase, held: frozenset[str]) -> Tensor:
        return torch.rand(1, 2, generator=self.rng, device=self.device) * 2.0 - 1.0


# ---------------------------------------------------------------------------------- runner


class Runner:
    """One truck, its action sources and the viewer state; :meth:`step` is one frame.

    Args:
        env: a ``TruckEnv`` with ``num_envs=1`` (already seeded).
        sources: action sources by mode name ("manual", "policy", "replay", "random").
        mode: the source used first.
        view: camera and panel layout.
        difficulty_step: change of difficulty per +/- key.
        wait_for_key: in "manual" mode, each episode waits for the first drive key (or P, ".")
            before its first step; :func:`run_loop` turns it on for a window.
        show_keys: key help in the panel (default: when there is a "manual" source).
    """

    def __init__(
        self,
        env: TruckEnv,
        sources: dict[str, ActionSource],
        mode: str,
        view: ViewConfig = ViewConfig(),  # noqa: B008 (frozen dataclass)
        difficulty_step: float = 0.5,
        wait_for_key: bool = False,
        show_keys: bool | None = None,
    ) -> None:
        if env.num_envs != 1:
            raise ValueError(f"the viewer drives one truck, got num_envs={env.num_envs}")
        check_choice("mode", mode, tuple(sources))
        self.env, self.sources, self.mode = env, sources, mode
        self.view, self.difficulty_step = view, difficulty_step
        self.wait_for_key = wait_for_key
        self.show_keys = "manual" in sources if show_keys is None else show_keys
        #: extra banner text for a finished episode (what a key does next; set by run_loop)
        self.done_hint = ""
        self.paused = False
        self.waiting = False
        self.episodes_done = 0
        self.frame_id = 0
        self._step_once = False
        self.new_scene()

    # -------------------------------------------------------------- episode control
    def new_scene(self) -> None:
        """A new random scene (the env's next episode)."""
        td = self.env.reset()
        self._start = self.env.get_state()
        self._camera = fixed_camera(self._start, self.view)
        self._begin(td)

    def restart(self) -> None:
        """The current scene again from its start pose."""
        self._begin(self.env.set_state(self._start))

    def _begin(self, td: TensorDictBase) -> None:
        self.td = td
        self.first_observation = td.select("observation", "lidar").clone()
        self.last: TensorDictBase | None = None
        self.last_action: Tensor | None = None
        self.episode_return = 0.0
        self.outcome: str | None = None
        self.waiting = self.wait_for_key and self.mode == "manual"
        self.render()

    def set_wait_for_key(self, on: bool) -> None:
        """Turn waiting for the first key on or off; applies to the current episode if unstarted."""
        self.wait_for_key = on
        unstarted = self.last is None and not self.ended
        self.waiting = on and unstarted and self.mode == "manual"
        self.render()

    @property
    def ended(self) -> bool:
        return self.outcome is not None

    def command(self, cmd: Command) -> None:
        """Apply a viewer command (everything but QUIT, which the loop handles)."""
        if cmd is Command.RESTART:
            self.restart()
            return
        if cmd is Command.NEW_SCENE:
            self.new_scene()
            return
        if cmd is Command.PAUSE:
            if self.waiting:  # P starts a waiting episode
                self.waiting = self.paused = False
            else:
                self.paused = not self.paused
        elif cmd is Command.STEP:
            self.paused, self._step_once, self.waiting = True, True, False
        elif cmd in (Command.HARDER, Command.EASIER):
            sign = 1.0 if cmd is Command.HARDER else -1.0
            d = self.env.get_difficulty() + sign * self.difficulty_step
            self.env.set_difficulty(min(MAX_DIFFICULTY, max(0.0, d)))
        elif cmd is Command.TOGGLE_MODE:
            if {"manual", "policy"} <= set(self.sources):
                self.mode = "policy" if self.mode == "manual" else "manual"
                self.waiting = False
        else:
            return
        self.render()

    def step(self, held: frozenset[str] = frozenset()) -> bool:
        """Advance one env step unless paused (or the episode has ended); True if it stepped.

        Raises:
            EndOfInput: the action source has nothing more to play.
        """
        if self.waiting and not self._step_once:
            if not set(held) & set(DRIVE_KEYS):
                return False
            self.waiting = False
            self.render()
        if self.ended or (self.paused and not self._step_once):
            return False
        self._step_once = False
        action = self.sources[self.mode](self.td, held)
        td = self.env.step(self.td.select("observation", "lidar").set("action", action))
        nxt = td["next"]
        self.last, self.last_action, self.td = nxt, action, nxt
        self.episode_return += float(nxt["reward"])
        if bool(nxt["done"]):
            self.episodes_done += 1
            self.outcome = next((o.label for o in OUTCOMES if bool(nxt[o.flag])), "DONE")
        self.render()
        return True

    # -------------------------------------------------------------- drawing
    def frame_state(self, s: TensorDictBase | None = None) -> FrameState:
        """The snapshot :func:`~truckrl.viz.video.render_frame` draws: the truck's state ``s``
        (default: the env's now) and this episode's bookkeeping."""
        env = self.env
        s = env.get_state()[0] if s is None else s
        keys = ("reward", *env.task.reward_keys)
        last = self.last
        return FrameState(
            state=s,
            ranges=self.td["lidar"][0] * env.config.lidar.max_range,
            task=env.task,
            config=env.config,
            tolerance=tuple(float(x[0]) for x in env.tolerances()),
            difficulty=env.get_difficulty(),
            rewards={} if last is None else {k: float(last[k]) for k in keys},
            last_action=None if self.last_action is None else self.last_action.reshape(-1).tolist(),
            episode_return=self.episode_return,
            outcome=self.outcome,
            mode=self.mode,
            waiting=self.waiting,
            paused=self.paused,
            episodes_done=self.episodes_done,
            done_hint=self.done_hint,
            key_rows=key_help("policy" in self.sources, env.task.reverse) if self.show_keys else (),
            camera=self._camera,
        )

    def render(self) -> None:
        """Draw the current state: ``self.view_image`` (bird's-eye view, with the waiting or
        outcome banner) and ``self.frame`` (view + HUD panel, what the window shows and videos
        record)."""
        self.view_image, self.frame = render_frame(self.frame_state(), self.view)
        self.frame_id += 1

    def hud(self, s: TensorDictBase) -> list[Line]:
        """HUD and key-help lines for the panel, from the truck's state ``s``."""
        return hud_lines(self.frame_state(s))


# ---------------------------------------------------------------------------------- loop
class CombinedInput:
    """Held keys and presses of two inputs together; ends when ``primary`` ends."""

    def __init__(self, primary, secondary) -> None:
        self.primary, self.secondary = primary, secondary

    def poll(self) -> KeyInput | None:
        a, b = self.primary.poll(), self.secondary.poll()
        if a is None:
            return None
        return KeyInput(a.held | b.held, a.pressed + b.pressed, a.quit or b.quit)


@dataclass
class LoopResult:
    frames: int = 0  # distinct frames shown (and recorded)
    steps: int = 0  # env steps taken
    outcomes: list[str] = field(default_factory=list)
    returns: list[float] = field(default_factory=list)


def run_loop(
    runner: Runner,
    inputs,
    *,
    window=None,
    fps: float = 10.0,
    max_frames: int | None = None,
    episodes: int | None = None,
    on_done: str = "new",
    done_hold_s: float = 1.0,
    sinks: tuple[Callable[[Runner], None], ...] = (),
) -> LoopResult:
    """The frame loop shared by keyboard and policy, window and headless.

    Each iteration polls ``inputs`` (``poll() -> KeyInput | None``; ``None`` ends the loop),
    applies pressed commands, advances one step, shows the frame in ``window`` (real time at
    ``fps``; headless runs as fast as it can) and hands every new frame to each of ``sinks``.

    When ``inputs`` is the window itself (a person at the keyboard), keyboard episodes wait for
    the first drive key (:attr:`Runner.waiting`) and a finished episode stays on screen, with its
    outcome banner, until a key is pressed or ``done_hold_s`` has passed.

    Args:
        max_frames: stop after this many distinct frames (the first, reset frame counts).
        episodes: stop when this many episodes have ended (``None``: until quit or input ends).
        on_done: after an episode: "new" scene, the "same" scene again, or "wait" for R/N
            (headless treats "wait" as "new").
        done_hold_s: [s] how long the window shows a finished episode before "new"/"same"
            (a key press moves on sooner).
    """
    result = LoopResult()
    ended_at: float | None = None  # [s] time.monotonic() when the shown episode ended
    if window is not None and inputs is window:
        _wait_for_person(runner, on_done)
    emit = _FrameEmitter(runner, result, sinks)
    emit()
    while max_frames is None or result.frames < max_frames:
        key = inputs.poll()
        if key is None or key.quit:
            break
        commands = [c for c in map(command_for, key.pressed) if c is not None]
        if Command.QUIT in commands:
            break
        if _apply_commands(runner, commands):
            ended_at = None
        if not _step(runner, key.held, result):
            break
        emit()
        if runner.ended and episodes is not None and runner.episodes_done >= episodes:
            break
        if runner.ended and (on_done != "wait" or window is None):
            ended_at = _hold_or_move_on(
                runner, bool(key.pressed), ended_at, on_done, window is None, done_hold_s
            )
            if ended_at is None and (max_frames is None or result.frames < max_frames):
                emit()
        if window is not None:
            window.show(runner.frame)
            window.tick(fps)
    return result


def _wait_for_person(runner: Runner, on_done: str) -> None:
    """A person at the window's keyboard: keyboard episodes wait for the first drive key, and a
    finished episode's banner says what a key does next (per ``on_done``)."""
    runner.done_hint = {
        "new": "any key: next scene",
        "same": "any key: again",
        "wait": "R: again   N: new scene",
    }.get(on_done, "")
    runner.set_wait_for_key(True)


class _FrameEmitter:
    """Calling it hands the runner's frame to each sink and counts it in ``result.frames``, once
    per distinct frame (a changed :attr:`Runner.frame_id`)."""

    def __init__(
        self, runner: Runner, result: LoopResult, sinks: tuple[Callable[[Runner], None], ...]
    ) -> None:
        self.runner, self.result, self.sinks = runner, result, sinks
        self.last_id: int | None = None

    def __call__(self) -> None:
        if self.runner.frame_id != self.last_id:
            self.last_id = self.runner.frame_id
            self.result.frames += 1
            for sink in self.sinks:
                sink(self.runner)


def _apply_commands(runner: Runner, commands: list[Command]) -> bool:
    """Apply the frame's viewer commands in order; True if one restarted the scene or began a
    new one (the end-of-episode hold starts over)."""
    began = False
    for cmd in commands:
        runner.command(cmd)
        if cmd in (Command.RESTART, Command.NEW_SCENE):
            began = True
    return began


def _step(runner: Runner, held: frozenset[str], result: LoopResult) -> bool:
    """One :meth:`Runner.step` with the held keys, counted in ``result`` (steps, and the outcome
    and return of an episode it ended); False when the action source has nothing more to play."""
    try:
        stepped = runner.step(held)
    except EndOfInput:
        return False
    result.steps += stepped
    if stepped and runner.ended:
        result.outcomes.append(runner.outcome)
        result.returns.append(runner.episode_return)
    return True


def _hold_or_move_on(
    runner: Runner,
    pressed: bool,
    ended_at: float | None,
    on_done: str,
    headless: bool,
    done_hold_s: float,
) -> float | None:
    """A finished episode: headless, or in a window after a key press or ``done_hold_s`` [s],
    restart it (``on_done="same"``) or begin a new scene, and return ``None``; otherwise keep
    showing it and return when it ended (``time.monotonic()`` [s], ``ended_at`` if already
    set). ``pressed``: keys were pressed this frame."""
    now = time.monotonic()
    key_after_end = ended_at is not None and pressed
    ended_at = now if ended_at is None else ended_at
    if headless or key_after_end or now - ended_at >= done_hold_s:
        if on_done == "same":
            runner.restart()
        else:
            runner.new_scene()
        return None
    return ended_at


class StripSink:
    """Keeps the bird's-eye views (resized to ``height`` px) for a frame strip."""

    def __init__(self, height: int) -> None:
        self.height = height
        self.frames: list[np.ndarray] = []

    def __call__(self, runner: Runner) -> None:
        img = runner.view_image
        self.frames.append(frame_strip(img[None], 1, self.height))
