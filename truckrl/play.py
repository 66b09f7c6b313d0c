"""``truckrl play``: drive the truck with the keyboard or watch a policy.

    truckrl play                                   # keyboard, paper controls
    truckrl play control=speed_angle seed=3 difficulty=2
    truckrl play checkpoint=outputs/DATE/TIME      # watch a policy (M: take over)
    truckrl play policy=onnx:policy.onnx           # an exported model, by onnxruntime
    truckrl play policy=planner seed=3             # the CEM planner's plan of each scene
    truckrl play policy=mypkg.drivers:make task=dock   # a user's factory
    truckrl play headless=true checkpoint=<run> record=run.mp4   # no window: to video
    truckrl play headless=true actions=docs/play_keys.txt strip=docs/play_strip.png

One frame loop (:func:`truckrl.viewer.runner.run_loop` over a :class:`~truckrl.viewer.runner.Runner`) serves every way of driving: an *action
source* turns the current observation and the held keys into the env action; the keyboard
(:class:`truckrl.viz.keyboard.KeyMapper`), a policy (its mean action), the planner
(:class:`PlannerSource`), a replayed ``.npy`` action array and a random policy are
interchangeable sources. The env is the training
``TruckEnv`` (one truck, same config groups, the same ``[-1, 1]`` action clamp and non-finite
guard) and every frame is its ``render_frame`` plus a HUD panel.

Inputs: a pygame window (:mod:`truckrl.viz.window`) or, with ``headless=true`` (pygame not
needed), a scripted key file (``actions=keys.txt``, format in :mod:`truckrl.viz.keyboard`) or
none. ``actions=file.npy`` replays an ``[F, 2]`` float array of actions instead. Headless with
neither a policy nor actions drives one episode with uniform random actions.

``policy=`` names what drives (:mod:`truckrl.rl.policy_specs`: ``checkpoint:PATH``,
``pretrained[:TASK]``, ``onnx:FILE``, ``planner``, ``module:function``; ``checkpoint=PATH`` is
short for ``policy=checkpoint:PATH``). A checkpoint's or an ONNX export's env and control config
are used (the policy was trained for them); a ``module:function`` policy and the planner drive
the env of the command line (``task=``, ``control=``, ``env.*``), the planner a checkpoint's
when ``checkpoint=`` is given too. ``seed``, ``difficulty`` (default: the policy's curriculum
difficulty) and ``device`` come from the command line. Fields: ``PlayConfig`` in
``truckrl/config/schemas.py``. Exit code 2 with a one-line message for a bad config, a policy
spec that cannot be used, a missing or corrupt checkpoint, or a bad actions file.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from truckrl.cli import hydra_entry

if TYPE_CHECKING:  # torch, TorchRL and OpenCV load on use: `--help` answers before them
    import numpy as np

    from truckrl.config.schemas import PlayConfig
    from truckrl.viewer.runner import LoopResult, Runner
    from truckrl.viz.keyboard import KeyInput


# ---------------------------------------------------------------------------------- sources
def load_actions(path: str | os.PathLike) -> np.ndarray | list[KeyInput]:
    """An ``.npy`` action array ``[F, 2]`` (values in [-1, 1]) or a parsed key script.

    Raises:
        ConfigError: missing file, wrong array shape, or a bad script line.
    """
    import numpy as np

    from truckrl.config.fields import ConfigError
    from truckrl.viz.keyboard import parse_key_script

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


def planner_config():
    """The planner's settings for ``policy=planner``: the defaults of
    :class:`~truckrl.planning.PlannerConfig` (the baseline of docs/planner.md), as ``truckrl eval
    policy=planner`` plans."""
    from truckrl.planning import PlannerConfig

    return PlannerConfig()


class PlannerSource:
    """The CEM planner as an action source: it plans the episode from the truck's state
    (:func:`truckrl.planning.plan_states`, at the env's current difficulty) and replays the
    plan's actions open loop, one per step; zeros past the plan's end.

    It plans again whenever the env's step counter is not the one the plan expects next: at a
    new scene, a restart, or after manual driving took over. Planning takes a moment (one
    scene's CEM search); the frame loop waits for it.
    """

    def __init__(self, env: Any, config: Any) -> None:
        self.env, self.config = env, config
        self.plan = None  # [T, 2] actions from step `start` on
        self.start = 0
        self.next = -1  # the step counter the plan expects at the next call

    def __call__(self, td: Any, held: frozenset[str]) -> Any:
        import torch

        from truckrl.planning import plan_states

        state = self.env.get_state()
        k = int(state["step_count"][0])
        if self.plan is None or k != self.next:
            d = self.env.get_difficulty()
            results, _, _ = plan_states(self.env.config, state, d, self.config, self.env.device)
            self.plan, self.start = results["actions"][0].to(self.env.device), k
        self.next = k + 1
        i = k - self.start
        if i >= len(self.plan):
            return torch.zeros(1, 2, device=self.env.device)
        return self.plan[i : i + 1]


# ---------------------------------------------------------------------------------- entry
def check_output(field: str, path: str | None) -> None:
    """Check an output file (``record=``, ``strip=``) can be written, before anything runs.

    Raises:
        ConfigError: one line naming the field, the path and the reason.
    """
    from truckrl.config.fields import ConfigError
    from truckrl.rl.session import check_dir_usable

    if not path:
        return
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{field}={path} is a directory; give a file name")
    try:
        check_dir_usable(p.parent if str(p.parent) else Path("."), "folder")
    except ConfigError as e:
        raise ConfigError(f"{field}={path} cannot be written: {e}") from None


def build_runner(pc: PlayConfig) -> tuple[Runner, Any, float, str]:
    """Env, sources and input for a validated config: ``(runner, input, fps, description)``."""
    import numpy as np

    from truckrl.env import TruckEnv
    from truckrl.rl.policy_specs import parse_policy_spec, resolve_policy, spec_of
    from truckrl.viewer.runner import (
        ArraySource,
        KeyboardSource,
        PolicySource,
        RandomSource,
        Runner,
    )
    from truckrl.viz.keyboard import NoKeys, ScriptedKeys

    actor = None
    env_cfg = pc.env
    difficulty = pc.difficulty
    what = "keyboard"
    spec = spec_of(pc.policy, pc.checkpoint)
    planner = spec is not None and spec.kind == "planner"
    if planner and pc.checkpoint:  # the planner in a checkpoint's env
        loaded = resolve_policy(parse_policy_spec(f"checkpoint:{pc.checkpoint}"), pc.device)
        env_cfg, own_difficulty = loaded.env_config, loaded.difficulty
        what = f"the CEM planner (env and control config from {loaded.path})"
    elif planner:
        own_difficulty, what = None, "the CEM planner"
    elif spec is not None:
        loaded = resolve_policy(spec, pc.device, env_cfg)
        actor, env_cfg, own_difficulty = loaded.actor, loaded.env_config, loaded.difficulty
        where = f"{loaded.path} " if loaded.path else ""
        what = f"policy {where}({spec.text}"
        what += "; env and control config from it)" if loaded.fixed_env else ")"
    if spec is not None:
        difficulty = own_difficulty if difficulty is None else difficulty
    script = load_actions(pc.actions) if pc.actions else None

    # one truck: torch.compile (the fast training preset's env.compile) would not pay for itself
    env_cfg = dataclasses.replace(env_cfg, compile=False)
    env = TruckEnv(num_envs=1, device=pc.device, config=env_cfg, seed=pc.seed)
    if difficulty is not None:
        env.set_difficulty(difficulty)
    sources: dict[str, Any] = {"manual": KeyboardSource(env, pc.keyboard)}
    mode = "manual"
    inputs: Any = NoKeys()
    if actor is not None:
        sources["policy"] = PolicySource(actor)
        mode = "policy"
    elif planner:
        sources["policy"] = PlannerSource(env, planner_config())
        mode = "policy"
    if isinstance(script, np.ndarray):
        sources["replay"] = ArraySource(script, pc.device)
        mode, what = "replay", f"actions {pc.actions}"
    elif script is not None:
        inputs, what = ScriptedKeys(script), f"key script {pc.actions}"
    elif pc.headless and mode == "manual":
        sources["random"] = RandomSource(pc.seed, pc.device)
        mode, what = "random", "random actions"
    fps = pc.fps if pc.fps is not None else 1.0 / env_cfg.dt  # default: real time
    runner = Runner(env, sources, mode, pc.view, pc.difficulty_step)
    return runner, inputs, fps, what


def play(pc: PlayConfig, key_state=None) -> LoopResult:
    """Run the viewer (window, or headless) until quit, the input ends or a limit is reached."""
    from truckrl.config.fields import ConfigError
    from truckrl.viewer.runner import CombinedInput, StripSink, run_loop
    from truckrl.viz.keyboard import ScriptedKeys
    from truckrl.viz.video import Mp4Writer, frame_strip, write_png

    check_output("record", pc.record)
    check_output("strip", pc.strip)
    runner, inputs, fps, what = build_runner(pc)
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


@hydra_entry("play", "PlayConfig")
def main(pc: PlayConfig, raw: Any) -> None:
    import torch

    torch.set_num_threads(pc.threads)
    play(pc)


if __name__ == "__main__":
    main()
