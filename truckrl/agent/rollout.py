"""Deterministic policy rollouts: fixed-seed evaluation episodes and single-episode videos."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.envs.utils import ExplorationType, set_exploration_type

from truckrl.env import ERROR_KEYS, EnvConfig, TruckEnv

OUTCOME_KEYS = ("success", "collision", "jackknife", "truncated")


@torch.no_grad()
def evaluate_policy(
    actor: TensorDictModuleBase,
    env_cfg: EnvConfig,
    difficulty: float,
    episodes: int,
    seed: int,
    device: str | torch.device = "cpu",
) -> tuple[dict[str, Tensor], tuple[float, float]]:
    """Run one episode in each of ``episodes`` seeded scenes with the mean action.

    All episodes run as one batch; each env's first episode is recorded at its first ``done``
    (every episode ends by ``env_cfg.max_steps``). The same ``seed`` gives the same scenes.

    Returns:
        ``(results, (position tolerance [m], heading tolerance [deg]))``; ``results`` holds
        per-episode ``[E]`` tensors on CPU: "success", "collision", "jackknife", "truncated"
        (bool), "length" [steps], "pos_error" [m], "tractor_heading_error" and
        "trailer_heading_error" [deg] at the episode's last step.
    """
    # eager: a one-off batch does not repay ~20 s of torch.compile
    env_cfg = dataclasses.replace(env_cfg, compile=False)
    env = TruckEnv(num_envs=episodes, device=device, config=env_cfg, seed=seed)
    env.set_difficulty(difficulty)
    tol_pos, tol_ang = env.tolerances()
    tolerance = (float(tol_pos[0]), math.degrees(float(tol_ang[0])))
    keys = (*OUTCOME_KEYS, *ERROR_KEYS, "step_count")
    rec = {k: torch.zeros(episodes, device=device) for k in keys}
    ended = torch.zeros(episodes, dtype=torch.bool, device=device)
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env_cfg.max_steps):
            nxt = env.step(actor(td))["next"]
            new = nxt["done"].squeeze(-1) & ~ended
            for k in keys:
                rec[k] = torch.where(new, nxt[k].squeeze(-1).to(torch.float32), rec[k])
            ended |= new
            if bool(ended.all()):
                break
            td = nxt
    env.close()
    out = {k: rec[k].bool().cpu() for k in OUTCOME_KEYS}
    out["length"] = rec["step_count"].cpu()
    out["pos_error"] = rec["pos_error"].cpu()
    for k in ERROR_KEYS[1:]:
        out[k] = rec[k].cpu() * (180.0 / math.pi)
    return out, tolerance


def summarize(results: dict[str, Tensor]) -> dict[str, float]:
    """Success/failure rates and mean / p95 of the final errors over episodes."""
    out: dict[str, float] = {"episodes": int(results["success"].numel())}
    for k in OUTCOME_KEYS:
        name = "timeout" if k == "truncated" else k
        out[f"{name}_rate"] = results[k].float().mean().item()
    out["mean_length"] = results["length"].mean().item()
    units = {"pos_error": "m", "tractor_heading_error": "deg", "trailer_heading_error": "deg"}
    for k, unit in units.items():
        v = results[k].to(torch.float64)
        out[f"{k}_{unit}_mean"] = v.mean().item()
        out[f"{k}_{unit}_p95"] = torch.quantile(v, 0.95).item()
    return out


@torch.no_grad()
def record_episode(
    actor: TensorDictModuleBase,
    env_cfg: EnvConfig,
    difficulty: float,
    seed: int,
    max_frames: int,
    device: str | torch.device = "cpu",
) -> np.ndarray:
    """Frames ``[F, H, W, 3]`` uint8 RGB of one deterministic episode (stops at its end)."""
    env_cfg = dataclasses.replace(env_cfg, compile=False)  # one truck: compiling does not pay
    env = TruckEnv(num_envs=1, device=device, config=env_cfg, seed=seed)
    env.set_difficulty(difficulty)
    td = env.reset()
    frames = [env.render_frame(0)]
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(max(0, max_frames - 1)):
            nxt = env.step(actor(td))["next"]
            frames.append(env.render_frame(0))
            if bool(nxt["done"].any()):
                break
            td = nxt
    env.close()
    return np.stack(frames)
