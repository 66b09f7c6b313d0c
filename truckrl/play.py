"""``python -m truckrl.play``: drive the truck with the keyboard or watch a policy.

    python -m truckrl.play                                   # keyboard, paper controls
    python -m truckrl.play control=speed_angle seed=3 difficulty=2
    python -m truckrl.play checkpoint=outputs/2025-01-01/12-00-00      # watch a policy (M: take over)
    python -m truckrl.play headless=true checkpoint=<run> record=run.mp4   # no window: to video
    python -m truckrl.play headless=true actions=docs/play_keys.txt strip=docs/play_strip.png

One frame loop (:func:`run_loop` over a :class:`Runner`) serves every way of driving: an *action
source* turns the current observation and the held keys into the env action; the keyboard
(:class:`truckrl.viz.keyboard.KeyMapper`), a policy (mean action of a checkpoint), a replayed
``.npy`` action array and a random policy are interchangeable sources. The env is the training
``TruckEnv`` (one truck, same config groups, the same ``[-1, 1]`` action clamp and non-finite
guard) and every frame is its ``render_frame`` plus a HUD panel.

Inputs: a pygame window (:mod:`truckrl.viz.window`) or, with ``headless=true`` (pygame not
needed), a scripted key file (``actions=keys.txt``, format in :mod:`truckrl.viz.keyboard`) or
none. ``actions=file.npy`` replays an ``[F, 2]`` float array of actions instead. Headless with
neither a checkpoint nor actions drives one episode with uniform random actions.

With a checkpoint, the env and control config come from the checkpoint (the policy was trained
for them); ``seed``, ``difficulty`` (default: the checkpoint's curriculum difficulty) and
``device`` come from the command line. Config: ``conf/play.yaml``. Exit code 2 with a one-line
message for a bad config, a missing or corrupt checkpoint, or a bad actions file.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.agent.checkpoint import CheckpointError, load_checkpoint, resolve_checkpoint
from truckrl.agent.network import ModelConfig, make_actor_critic
from truckrl.env import REWARD_TERMS, EnvConfig, TruckEnv
from truckrl.sim.control import ControlConfig
from truckrl.sim.validation import ConfigError, check_choice, check_range, from_mapping
from truckrl.viz.draw import COLORS
from truckrl.viz.keyboard import (
    KEY_HELP,
    Command,
    KeyboardConfig,
    KeyInput,
    KeyMapper,
    NoKeys,
    ScriptedKeys,
    command_for,
    parse_key_script,
)
from truckrl.viz.panel import Line, with_panel
from truckrl.viz.video import Mp4Writer, frame_strip, write_png

CONFIG_PATH = str(Path(__file__).resolve().parent.parent / "conf")
ON_DONE = ("new", "same", "wait")
_OK, _BAD, _NOTE = COLORS["goal"], (255, 95, 95), COLORS["lidar"]

#: An action source: (current observation td ``[1]``, held drive keys) -> action ``[1, 2]``.
ActionSource = Callable[[TensorDictBase, frozenset[str]], Tensor]


class EndOfInput(Exception):
    """An action source or input script has nothing more to play."""


# ---------------------------------------------------------------------------------- config
@dataclass(frozen=True)
class ViewConfig:
    """Camera and frame layout (``view.*``)."""

    follow: bool = False
    size_px: int = 640
    half_extent: float = 40.0
    margin: float = 15.0
    panel_px: int = 340

    def __post_init__(self) -> None:
        if not isinstance(self.follow, bool):
            raise ConfigError(f"view.follow = {self.follow!r} must be true or false")
        check_range("view.size_px", self.size_px, 64, 4096)
        check_range("view.half_extent", self.half_extent, 1.0, 1e4)
        check_range("view.margin", self.margin, 0.0, 1e4)
        check_range("view.panel_px", self.panel_px, 0, 4096)


@dataclass(frozen=True)
class PlayConfig:
    """The validated viewer options of ``conf/play.yaml`` (env and control are validated by
    :class:`EnvConfig`)."""

    seed: int = 0
    device: str = "cpu"
    threads: int = 1
    checkpoint: str | None = None
    actions: str | None = None
    headless: bool = False
    record: str | None = None
    strip: str | None = None
    strip_frames: int = 5
    strip_height: int = 300
    difficulty: float | None = None
    difficulty_step: float = 0.5
    fps: float | None = None
    max_frames: int | None = None
    episodes: int | None = None
    on_done: str = "new"
    done_hold_s: float = 1.0
    view: ViewConfig = field(default_factory=ViewConfig)
    keyboard: KeyboardConfig = field(default_factory=KeyboardConfig)

    def __post_init__(self) -> None:
        check_range("seed", self.seed, 0, 2**62)
        check_range("threads", self.threads, 1, 1024)
        try:
            torch.device(self.device)
        except (RuntimeError, TypeError):
            raise ConfigError(f"device = {self.device!r} is not a torch device") from None
        if not isinstance(self.headless, bool):
            raise ConfigError(f"headless = {self.headless!r} must be true or false")
        if self.checkpoint and self.actions:
            raise ConfigError("give checkpoint or actions, not both")
        check_range("strip_frames", self.strip_frames, 1, 100)
        check_range("strip_height", self.strip_height, 16, 4096)
        if self.difficulty is not None:
            check_range("difficulty", self.difficulty, 0.0, 30.0)
        check_range("difficulty_step", self.difficulty_step, 0.0, 30.0, lo_open=True)
        if self.fps is not None:
            check_range("fps", self.fps, 0.0, 1000.0, lo_open=True)
        if self.max_frames is not None:
            check_range("max_frames", self.max_frames, 1, 1e9)
        if self.episodes is not None:
            check_range("episodes", self.episodes, 1, 1e9)
        check_choice("on_done", self.on_done, ON_DONE)
        check_range("done_hold_s", self.done_hold_s, 0.0, 3600.0)
        object.__setattr__(self, "view", from_mapping(ViewConfig, self.view, "view"))
        object.__setattr__(
            self, "keyboard", from_mapping(KeyboardConfig, self.keyboard, "keyboard")
        )

    @classmethod
    def from_hydra(cls, cfg: DictConfig) -> PlayConfig:
        c = OmegaConf.to_container(cfg, resolve=True)
        for k in ("env", "control", "hydra"):
            c.pop(k, None)
        return from_mapping(cls, c, "play")


# ---------------------------------------------------------------------------------- sources
@torch.no_grad()
def load_policy(
    checkpoint: str | os.PathLike, device: str | torch.device = "cpu"
) -> tuple[Any, EnvConfig, float, Path]:
    """Rebuild the actor of a training checkpoint.

    Returns:
        ``(actor, env config, curriculum difficulty, checkpoint file)``; the actor is a TorchRL
        module reading "observation" and "lidar" and writing "action" (the mean under
        ``ExplorationType.DETERMINISTIC``).

    Raises:
        CheckpointError: missing, corrupt, or weights that do not fit the saved config.
    """
    path = resolve_checkpoint(checkpoint)
    state = load_checkpoint(path, map_location=device)
    try:
        saved = OmegaConf.create(state["config"])
        env_cfg = EnvConfig.from_hydra(saved.env, saved.control)
        model_cfg = from_mapping(ModelConfig, OmegaConf.to_container(saved.model), "model")
        ac = make_actor_critic(model_cfg, int(state["num_obs"]), int(state["num_beams"]))
        ac.model.load_state_dict(state["model"])
        difficulty = float(state["curriculum"]["difficulty"])
    except (KeyError, AttributeError, TypeError, ValueError, RuntimeError, ConfigError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"{path}: not a usable policy checkpoint ({first})") from None
    ac.model.to(device).eval()
    return ac.actor, env_cfg, difficulty, path


class PolicySource:
    """The policy's mean action (deterministic playback)."""

    def __init__(self, actor) -> None:
        self.actor = actor

    @torch.no_grad()
    def __call__(self, td: TensorDictBase, held: frozenset[str]) -> Tensor:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return self.actor(td.select("observation", "lidar"))["action"]


def commanded_values(state: TensorDictBase, control: ControlConfig, min_speed: float):
    """The commanded quantities' present values on the action scale ``(u_lon, u_lat)``.

    Inverse of the control's affine map (``u * max_q``; speed: ``[-1, 1] -> [min_speed,
    max_speed]``) applied to the truck's current speed/accel/jerk and steer/rate/accel.
    """
    p = state["params"]
    lon = control.longitudinal
    if lon == "speed":
        span = float(p["max_speed"]) - min_speed
        u_lon = 2.0 * (float(state["speed"]) - min_speed) / span - 1.0
    else:  # accel | jerk: the state key and the limit share the name
        u_lon = float(state[lon]) / float(p[f"max_{lon}"])
    key = {"angle": "steer", "rate": "steer_rate", "accel": "steer_accel"}[control.lateral]
    u_lat = float(state[key]) / float(p[f"max_{key}"])
    return u_lon, u_lat


class KeyboardSource:
    """Held keys -> action through :class:`KeyMapper` (set-points read from the truck's state)."""

    def __init__(self, env: TruckEnv, cfg: KeyboardConfig) -> None:
        self.env = env
        self.mapper = KeyMapper(env.config.control, cfg, env.config.dt)

    def __call__(self, td: TensorDictBase, held: frozenset[str]) -> Tensor:
        cfg = self.env.config
        current = commanded_values(self.env.state_of(0), cfg.control, cfg.vehicle.min_speed)
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


def load_actions(path: str | os.PathLike) -> np.ndarray | list[KeyInput]:
    """An ``.npy`` action array ``[F, 2]`` (values in [-1, 1]) or a parsed key script.

    Raises:
        ConfigError: missing file, wrong array shape, or a bad script line.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"actions file not found: {p}")
    if p.suffix == ".npy":
        try:
            arr = np.load(p, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise ConfigError(f"actions file {p} is not a readable .npy array ({e})") from None
        if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0:
            raise ConfigError(f"actions array {p} must have shape [F >= 1, 2], got {arr.shape}")
        if not np.issubdtype(arr.dtype, np.number):
            raise ConfigError(f"actions array {p} must be numeric, got {arr.dtype}")
        return arr.astype(np.float32)
    return parse_key_script(p.read_text(), str(p))


# ---------------------------------------------------------------------------------- runner
_OUTCOMES = (
    ("success", "SUCCESS", _OK),
    ("collision", "COLLISION", _BAD),
    ("jackknife", "JACK-KNIFE", _BAD),
    ("truncated", "TIMEOUT", _BAD),
)


class Runner:
    """One truck, its action sources and the viewer state; :meth:`step` is one frame.

    Args:
        env: a ``TruckEnv`` with ``num_envs=1`` (already seeded).
        sources: action sources by mode name ("manual", "policy", "replay", "random").
        mode: the source used first.
        view: camera and panel layout.
        difficulty_step: change of difficulty per +/- key.
    """

    def __init__(
        self,
        env: TruckEnv,
        sources: dict[str, ActionSource],
        mode: str,
        view: ViewConfig = ViewConfig(),  # noqa: B008 (frozen dataclass)
        difficulty_step: float = 0.5,
    ) -> None:
        if env.num_envs != 1:
            raise ValueError(f"the viewer drives one truck, got num_envs={env.num_envs}")
        check_choice("mode", mode, tuple(sources))
        self.env, self.sources, self.mode = env, sources, mode
        self.view, self.difficulty_step = view, difficulty_step
        self.paused = False
        self.episodes_done = 0
        self.frame_id = 0
        self._step_once = False
        self.new_scene()

    # -------------------------------------------------------------- episode control
    def new_scene(self) -> None:
        """A new random scene (the env's next episode)."""
        td = self.env.reset()
        self._start = self.env.state_of(0).unsqueeze(0)
        self._begin(td)

    def restart(self) -> None:
        """The current scene again from its start pose."""
        self._begin(self.env.reset_to(self._start))

    def _begin(self, td: TensorDictBase) -> None:
        self.td = td
        self.first_observation = td.select("observation", "lidar").clone()
        self.last: TensorDictBase | None = None
        self.last_action: Tensor | None = None
        self.episode_return = 0.0
        self.outcome: str | None = None
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
            self.paused = not self.paused
        elif cmd is Command.STEP:
            self.paused, self._step_once = True, True
        elif cmd in (Command.HARDER, Command.EASIER):
            sign = 1.0 if cmd is Command.HARDER else -1.0
            d = self.env.get_difficulty() + sign * self.difficulty_step
            self.env.set_difficulty(min(30.0, max(0.0, d)))
        elif cmd is Command.TOGGLE_MODE:
            if {"manual", "policy"} <= set(self.sources):
                self.mode = "policy" if self.mode == "manual" else "manual"
        else:
            return
        self.render()

    def step(self, held: frozenset[str] = frozenset()) -> bool:
        """Advance one env step unless paused (or the episode has ended); True if it stepped.

        Raises:
            EndOfInput: the action source has nothing more to play.
        """
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
            self.outcome = next((name for k, name, _ in _OUTCOMES if bool(nxt[k])), "DONE")
        self.render()
        return True

    # -------------------------------------------------------------- drawing
    def render(self) -> None:
        """Draw the current state: ``self.view_image`` (bird's-eye view) and ``self.frame``
        (view + HUD panel, what the window shows and videos record)."""
        s = self.env.state_of(0)
        t = int(s["step_count"]) * self.env.config.dt
        kwargs: dict[str, Any] = {"size_px": self.view.size_px}
        if self.view.follow:
            kwargs["view_half_extent"] = self.view.half_extent
        else:
            a, b = self._start["pose"][0, :2], self._start["goal"][0, :2]
            half = 0.5 * float((b - a).norm()) + self.view.margin
            kwargs.update(center=0.5 * (a + b), view_half_extent=max(self.view.half_extent, half))
        caption = f"t {t:4.1f} s  v {float(s['speed']):4.1f} m/s"
        if self.outcome:
            caption += f"  {self.outcome}"
        self.view_image = self.env.render_frame(0, hud_lines=[caption], **kwargs)
        self.frame = with_panel(self.view_image, self.hud(s), self.view.panel_px)
        self.frame_id += 1

    def hud(self, s: TensorDictBase) -> list[Line]:
        """HUD and key-help lines for the panel, from the truck's state ``s``."""
        cfg = self.env.config
        deg = 180.0 / math.pi
        tol_pos, tol_ang = (float(x[0]) for x in self.env.tolerances())
        status = "PAUSED" if self.paused else ""
        lines: list[Line] = [
            (f"mode {self.mode.upper()}  {status}", _NOTE if self.paused else COLORS["hud"]),
            f"control {cfg.control.longitudinal} / {cfg.control.lateral}",
            f"step {int(s['step_count'])}/{cfg.max_steps}   scenes {self.episodes_done}",
            f"speed {float(s['speed']):6.2f} m/s  acc {float(s['accel']):+5.2f}",
            f"steer {float(s['steer']) * deg:+6.1f} deg  rate {float(s['steer_rate']) * deg:+5.1f}",
            f"articulation {float(s['pose'][3]) * deg:+6.1f} deg",
            "",
            f"goal dist {float(s['pos_error']):6.2f} m (tol {tol_pos:.2f})",
            f"tractor err {float(s['tractor_heading_error']) * deg:5.1f} deg (tol {tol_ang * deg:.1f})",
            f"trailer err {float(s['trailer_heading_error']) * deg:5.1f} deg",
            f"difficulty {self.env.get_difficulty():.1f}",
            "",
        ]
        last = self.last
        r = {k: 0.0 if last is None else float(last[k]) for k in ("reward", *REWARD_TERMS)}
        lines += [
            f"return {self.episode_return:+8.3f}  last {r['reward']:+.3f}",
            f" progress {r['r_progress']:+.3f}  time {r['r_time']:+.2f}",
            f" heading  {r['r_tractor_heading']:+.3f}  trailer {r['r_trailer_heading']:+.3f}",
            f" success {r['r_success']:+.0f} crash {r['r_collision']:+.0f} timeout {r['r_timeout']:+.0f}",
        ]
        if self.last_action is not None:
            a = self.last_action.reshape(-1).tolist()
            lines.append(f" action {a[0]:+.2f} {a[1]:+.2f}")
        color = next((c for _, name, c in _OUTCOMES if name == self.outcome), COLORS["hud"])
        lines += [(f"outcome {self.outcome or 'driving'}", color), ""]
        lines += [f"{k}\t{v}" for k, v in KEY_HELP]
        return lines


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

    Args:
        max_frames: stop after this many distinct frames (the first, reset frame counts).
        episodes: stop when this many episodes have ended (``None``: until quit or input ends).
        on_done: after an episode: "new" scene, the "same" scene again, or "wait" for R/N
            (headless treats "wait" as "new").
        done_hold_s: [s] how long the window shows a finished episode before "new"/"same".
    """
    result = LoopResult()
    last_id = None
    ended_at: float | None = None

    def emit() -> None:
        nonlocal last_id
        if runner.frame_id != last_id:
            last_id = runner.frame_id
            result.frames += 1
            for sink in sinks:
                sink(runner)

    emit()
    while max_frames is None or result.frames < max_frames:
        key = inputs.poll()
        if key is None or key.quit:
            break
        commands = [c for c in map(command_for, key.pressed) if c is not None]
        if Command.QUIT in commands:
            break
        for cmd in commands:
            runner.command(cmd)
            if cmd in (Command.RESTART, Command.NEW_SCENE):
                ended_at = None
        try:
            stepped = runner.step(key.held)
        except EndOfInput:
            break
        result.steps += stepped
        if stepped and runner.ended:
            result.outcomes.append(runner.outcome)
            result.returns.append(runner.episode_return)
        emit()
        if runner.ended and episodes is not None and runner.episodes_done >= episodes:
            break
        if runner.ended and (on_done != "wait" or window is None):
            now = time.monotonic()
            ended_at = now if ended_at is None else ended_at
            if window is None or now - ended_at >= done_hold_s:
                if on_done == "same":
                    runner.restart()
                else:
                    runner.new_scene()
                ended_at = None
                if max_frames is None or result.frames < max_frames:
                    emit()
        if window is not None:
            window.show(runner.frame)
            window.tick(fps)
    return result


class StripSink:
    """Keeps the bird's-eye views (resized to ``height`` px) for a frame strip."""

    def __init__(self, height: int) -> None:
        self.height = height
        self.frames: list[np.ndarray] = []

    def __call__(self, runner: Runner) -> None:
        img = runner.view_image
        self.frames.append(frame_strip(img[None], 1, self.height))


# ---------------------------------------------------------------------------------- entry
def build(pc: PlayConfig, env_cfg: EnvConfig) -> tuple[Runner, Any, float, str]:
    """Env, sources and input for a validated config: ``(runner, input, fps, description)``."""
    actor = None
    difficulty = pc.difficulty
    what = "keyboard"
    if pc.checkpoint:
        actor, env_cfg, ckpt_difficulty, path = load_policy(pc.checkpoint, pc.device)
        difficulty = ckpt_difficulty if difficulty is None else difficulty
        what = f"policy {path} (env and control config from the checkpoint)"
    script = load_actions(pc.actions) if pc.actions else None

    # one truck: torch.compile (the fast training preset's env.compile) would not pay for itself
    env_cfg = dataclasses.replace(env_cfg, compile=False)
    env = TruckEnv(num_envs=1, device=pc.device, config=env_cfg, seed=pc.seed)
    if difficulty is not None:
        env.set_difficulty(difficulty)
    sources: dict[str, ActionSource] = {"manual": KeyboardSource(env, pc.keyboard)}
    mode = "manual"
    inputs: Any = NoKeys()
    if actor is not None:
        sources["policy"] = PolicySource(actor)
        mode = "policy"
    if isinstance(script, np.ndarray):
        sources["replay"] = ArraySource(script, pc.device)
        mode, what = "replay", f"actions {pc.actions}"
    elif script is not None:
        inputs, what = ScriptedKeys(script), f"key script {pc.actions}"
    elif pc.headless and actor is None:
        sources["random"] = RandomSource(pc.seed, pc.device)
        mode, what = "random", "random actions"
    fps = pc.fps if pc.fps is not None else 1.0 / env_cfg.dt  # default: real time
    runner = Runner(env, sources, mode, pc.view, pc.difficulty_step)
    return runner, inputs, fps, what


def play(pc: PlayConfig, env_cfg: EnvConfig, key_state=None) -> LoopResult:
    """Run the viewer (window, or headless) until quit, the input ends or a limit is reached."""
    runner, inputs, fps, what = build(pc, env_cfg)
    window = None
    if not pc.headless:
        try:
            from truckrl.viz.window import Window
        except ImportError:
            raise ConfigError(
                "the window needs pygame (pip install 'truckrl[viewer]'); or use headless=true"
            ) from None
        try:
            window = Window(runner.frame.shape[1::-1], "truckrl play", key_state)
        except Exception as e:  # pygame.error: no display available
            raise ConfigError(f"cannot open a window ({e}); use headless=true") from None
        if window.driver in ("offscreen", "dummy") and not os.environ.get("SDL_VIDEODRIVER"):
            window.close()
            raise ConfigError(
                f"no display (SDL fell back to its {window.driver!r} video driver): use "
                f"headless=true, or set SDL_VIDEODRIVER={window.driver} to run the window unseen"
            )
        inputs = CombinedInput(inputs, window) if isinstance(inputs, ScriptedKeys) else window
    episodes = pc.episodes if pc.episodes is not None or window else 1
    sinks: list[Callable[[Runner], None]] = []
    writer = Mp4Writer(pc.record, fps) if pc.record else None
    if writer:
        sinks.append(lambda r: writer.write(r.frame))
    strip = StripSink(pc.strip_height) if pc.strip else None
    if strip:
        sinks.append(strip)
    print(f"play: {what}; seed {pc.seed}, difficulty {runner.env.get_difficulty()}")
    try:
        result = run_loop(
            runner,
            inputs,
            window=window,
            fps=fps,
            max_frames=pc.max_frames,
            episodes=episodes,
            on_done=pc.on_done,
            done_hold_s=pc.done_hold_s,
            sinks=tuple(sinks),
        )
    finally:
        if writer:
            writer.close()
        if window:
            window.close()
    for i, (o, r) in enumerate(zip(result.outcomes, result.returns, strict=True), start=1):
        print(f"episode {i}: {o}, return {r:+.3f}")
    print(f"{result.frames} frames, {result.steps} steps")
    if writer:
        print(f"video: {writer.path} ({writer.frames} frames at {fps:g} fps)")
    if strip:
        png = write_png(
            pc.strip, frame_strip(strip.frames, pc.strip_frames, pc.strip_height, gap_px=6)
        )
        print(f"strip: {png}")
    return result


@hydra.main(version_base=None, config_path=CONFIG_PATH, config_name="play")
def main(cfg: DictConfig) -> None:
    try:
        pc = PlayConfig.from_hydra(cfg)
        torch.set_num_threads(pc.threads)
        play(pc, EnvConfig.from_hydra(cfg.env, cfg.control))
    except (ConfigError, CheckpointError) as e:
        print(f"{type(e).__name__}: {e}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
