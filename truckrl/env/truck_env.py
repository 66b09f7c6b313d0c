"""TruckEnv: N articulated trucks as one batched TorchRL environment over a task core.

One :class:`TruckEnv` holds ``num_envs`` independent episodes as tensors (``batch_size=[N]``); every
physics, collision and LiDAR step is one set of tensor ops over all N, on CPU or CUDA. The env is a
thin adapter: what happens in a step is :meth:`truckrl.tasks.base.Task.transition`; the env owns
the specs (keys, shapes and the observation table: :mod:`truckrl.env.spec`), partial resets,
seeding and the curriculum difficulty. Fresh episodes come from an
:class:`~truckrl.env.pool.EpisodePool`, the step reads the scene through a
:class:`~truckrl.env.compaction.CompactScene` (where
:attr:`~truckrl.tasks.base.Task.compact_scene`), and ``step_and_maybe_reset`` restarts trucks
in place (:mod:`truckrl.env.autoreset`). Stack several with
``ParallelEnv(W, lambda: TruckEnv(num_envs=n))`` for a ``[W, n]`` batch.

State: :meth:`TruckEnv.get_state` returns a copy of the full state (layout in
:mod:`truckrl.tasks.base`); :meth:`TruckEnv.set_state` starts every truck from a given state;
:attr:`TruckEnv.params` is the live vehicle-parameter sub-tensordict (read it, or write it between
steps to change the trucks).
"""

from __future__ import annotations

from collections.abc import Hashable
from numbers import Integral
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from truckrl.config.fields import ConfigError, build, check_range
from truckrl.env.autoreset import InPlaceAutoReset
from truckrl.env.compaction import CompactScene
from truckrl.env.pool import EpisodePool, Leaves, Observation
from truckrl.env.spec import build_specs
from truckrl.sim.compiled import compile_sim
from truckrl.sim.control import CONTROL_KEYS
from truckrl.sim.vehicle import PARAM_KEYS, REVERSE_KEYS
from truckrl.tasks import FLAG_KEYS, MAX_DIFFICULTY, EnvConfig, Task, make_task


class TruckEnv(InPlaceAutoReset, EnvBase):
    """Batched tractor-trailer environment; see the module docstring for specs and state.

    Args:
        num_envs: number of trucks N held as one batch (``batch_size=[N]``).
        device: torch device for all state and outputs.
        config: :class:`~truckrl.tasks.config.EnvConfig`, a mapping of its fields, or ``None``.
        seed: seed of the scene/vehicle generator; ``None`` draws one from torch's global RNG.
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int = 1,
        device: torch.device | str = "cpu",
        config: EnvConfig | dict | None = None,
        seed: int | None = None,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, Integral) or num_envs < 1:
            raise ConfigError(f"num_envs = {num_envs!r} must be a whole number >= 1")
        num_envs = int(num_envs)
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.config = build(EnvConfig, config, "env")
        self.num_envs = num_envs
        self.task = make_task(self.config).to(self.device)
        self._state: TensorDict | None = None
        self._restore: TensorDictBase | None = None  # state for the next reset (set_state)
        self._scene = (
            CompactScene(grow_only=self.config.compile) if self.task.compact_scene else None
        )
        self._difficulty = torch.full(
            (num_envs,), self.config.tolerance.difficulty, device=self.device
        )
        #: the difficulty as a float (all trucks share it), and the state keys left out of the
        #: step while every episode of the batch started at a difficulty where the task can go
        #: without them (Task.idle_keys); kept on the host, so the step reads no device value
        self._host_difficulty = float(self.config.tolerance.difficulty)
        self._idle: tuple[str, ...] = ()
        self._state_keys = ("pose", "goal", "segments", "mask", "step_count", *CONTROL_KEYS)
        self._state_keys += (*self.task.error_keys, *self.task.extra_state_keys)
        self._param_keys = (*PARAM_KEYS, *(REVERSE_KEYS if self.task.reverse else ()))
        specs = build_specs(self.task, num_envs, self.config.lidar.num_beams, self.device)
        for name, spec in specs.items():
            setattr(self, name, spec)
        #: Leaves a reset sets to zero / False: reward terms, flags and done signals.
        self._reset_zero_keys = frozenset(
            (*self.task.reward_keys, *FLAG_KEYS, "done", "terminated", "truncated")
        )
        #: (key, shape, dtype) of every observation leaf, for the zero rows of a partial reset.
        self._obs_zero = tuple(
            (k, tuple(spec.shape), spec.dtype) for k, spec in self.observation_spec.items()
        )
        compile_fn = (
            (lambda f: compile_sim(f, self.device)) if self.config.compile else (lambda f: f)
        )
        self._transition_fn = compile_fn(self.task.transition)
        self._observe_fn = compile_fn(self.task.observe)
        # the observation of fresh episodes (a pool refill, or the trucks a partial reset of a
        # task with a start curriculum restarts): their count changes from call to call, so
        # one graph with a symbolic batch size instead of one per count
        self._observe_rows_fn = (
            compile_sim(self.task.observe, self.device, dynamic=True)
            if self.config.compile
            else None
        )
        # the pool holds its episodes as they start at the current difficulty, with their first
        # observation: a partial reset then copies plain tensors and never builds a TensorDict
        # or observes (see _restart); a task without a start curriculum prepares them once
        self._plain_reset = type(self.task).on_reset is Task.on_reset
        self._pool = EpisodePool(
            self._draw, self.config.episode_pool, self._prepare, self._draw_key
        )
        #: what the task's last refill left for the next one (:meth:`Task.sample_pool`)
        self._carry = None
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_().item())
        self.set_seed(seed)

    # ------------------------------------------------------------------ seeding / curriculum
    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_().item())
        self.rng = torch.Generator(device=self.device)
        self.rng.manual_seed(int(seed))
        self._pool.clear()
        self._carry = None

    def set_difficulty(self, difficulty: float) -> None:
        """Set the curriculum difficulty ``d`` (>= 0) for every truck; used from the next step on.

        Tolerances become ``position * 2**-d`` metres and ``heading_deg * 2**-d`` degrees.
        """
        d = check_range("difficulty", difficulty, 0.0, MAX_DIFFICULTY)
        self._difficulty.fill_(d)
        self._host_difficulty = d
        # the episodes started from now on start at d: keep only what is idle there too
        idle = self.task.idle_keys(d)
        self._idle = tuple(k for k in self._idle if k in idle)

    @property
    def difficulty(self) -> float:
        """Current difficulty (all trucks share it)."""
        return self.get_difficulty()

    def get_difficulty(self) -> float:
        """Current difficulty; a method, so ``ParallelEnv`` dispatches it to every worker."""
        return float(self._difficulty[0])

    def tolerances(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-truck ``(position [m], heading [rad])`` tolerances, each ``[N]``."""
        return self.task.tolerances(self._difficulty)

    # ------------------------------------------------------------------ state
    def get_state(self) -> TensorDict:
        """A copy of the full state ``[N]`` (layout in :mod:`truckrl.tasks.base`)."""
        if self._state is None:
            raise RuntimeError("get_state() needs reset() first")
        return self._state.clone()

    def set_state(self, state: TensorDictBase) -> TensorDictBase:
        """Start every truck from ``state`` (``[N]``, as from :meth:`get_state`) and return the
        reset tensordict (observation of that state, done flags cleared).

        Replays an episode from a saved start without drawing from the scene generator, so the
        sequence of later random scenes is unchanged.
        """
        if tuple(state.batch_size) != (self.num_envs,):
            raise ValueError(
                f"set_state needs a state of batch size [{self.num_envs}], "
                f"got {list(state.batch_size)}"
            )
        self._restore = self.task.complete_state(state.to(self.device).clone())
        return self.reset()

    @property
    def params(self) -> TensorDict:
        """Live vehicle parameters ``{key: [N]}``; writes change the trucks from the next step."""
        if self._state is None:
            raise RuntimeError("params needs reset() first")
        return self._state["params"]

    # ------------------------------------------------------------------ fresh episodes
    def _draw(self, k: int, draw_key: Hashable) -> Leaves:
        """Up to ``k`` fresh episodes from the task's generator (the pool's refill,
        :meth:`Task.sample_pool`), what it carries to the next refill kept here."""
        td, self._carry = self.task.sample_pool(k, self.rng, self.device, draw_key, self._carry)
        return dict(td.items(include_nested=True, leaves_only=True))

    def _draw_key(self, pool_key: float | None) -> Hashable:
        """What the pool's draws depend on (:meth:`Task.draw_key` of the difficulty; nothing
        for a task without a start curriculum)."""
        return None if pool_key is None else self.task.draw_key(pool_key)

    def _pool_key(self) -> float | None:
        """What the pool's prepared episodes depend on: the difficulty (all trucks share it),
        or nothing for a task without a start curriculum."""
        return None if self._plain_reset else self._host_difficulty

    def _prepare(self, leaves: Leaves, difficulty: float | None) -> tuple[Leaves, Observation]:
        """Drawn episodes as they start at ``difficulty`` (:meth:`Task.on_reset`; ``None``: as
        drawn) and their first observation, the ``difficulty`` column left out
        (:meth:`_restart` adds each truck's own)."""
        m = next(iter(leaves.values())).shape[0]
        d = torch.full((m,), 0.0 if difficulty is None else difficulty, device=self.device)
        if difficulty is not None:
            td = self.task.on_reset(self._as_tensordict(leaves, m), d)
            leaves = dict(td.items(include_nested=True, leaves_only=True))
        obs = self._observe_rows(self._flat_rows(leaves), d)
        del obs["difficulty"]
        return leaves, obs

    def _as_tensordict(self, leaves: Leaves, m: int) -> TensorDict:
        """State leaves ``{leaf key: [m, ...]}`` as a (nested) TensorDict ``[m]``, built from
        nested dicts in one call (cheaper than a ``set`` per leaf)."""
        root: dict[str, Any] = {}
        for key, value in leaves.items():
            *outer, last = key if isinstance(key, tuple) else (key,)
            node = root
            for k in outer:
                node = node.setdefault(k, {})
            node[last] = value
        return TensorDict(root, batch_size=[m], device=self.device)

    def _flat_rows(self, leaves: Any) -> dict[str, Any]:
        """State leaves (``{leaf key: [m, ...]}`` or a state TensorDict) as the flat state the
        task functions read: plain tensors, ``params`` as a dict."""
        flat: dict[str, Any] = {k: leaves[k] for k in self._state_keys if k not in self._idle}
        flat["params"] = {k: leaves["params", k] for k in self._param_keys}
        return flat

    def _observe_rows(self, flat: dict[str, Any], difficulty: torch.Tensor) -> Observation:
        """:meth:`Task.observe` of a few rows ``[m]``: compiled with a symbolic batch size under
        ``env.compile`` (a count of 1 would be a graph of its own, so it runs eagerly)."""
        if self._observe_rows_fn is not None and difficulty.shape[0] > 1:
            return dict(self._observe_rows_fn(flat, difficulty))
        return dict(self.task.observe(flat, difficulty))

    def _flat_state(self) -> dict[str, Any]:
        """The whole state as plain tensors, ``params`` as a dict, and ``segments`` and ``mask``
        the compacted scene (:class:`~truckrl.env.compaction.CompactScene`; the state's own where
        the task reads no compacted scene)."""
        flat = self._flat_rows(self._state)
        if self._scene is not None and self._scene.view is not None:
            flat["segments"], flat["mask"] = self._scene.view
        return flat

    # ------------------------------------------------------------------ reset / step
    def _restart(self, idx: torch.Tensor) -> Observation:
        """Start fresh episodes for the trucks ``idx`` (``[m]`` int64, ``m >= 1``) in the state
        and return their first observation ``{key: [m, ...]}``.

        The episodes come from the pool in order, prepared for the trucks' difficulty
        (:meth:`Task.on_reset` applied, the first observation computed: :meth:`_prepare`).
        """
        difficulty = self._difficulty[idx]
        fresh, obs = self._pool.take(idx.numel(), self._pool_key())
        for key, value in fresh.items():
            self._state.get(key).index_put_((idx,), value)
        if self._scene is not None:
            self._scene.update(self._state["segments"], self._state["mask"], idx)
        return {**obs, "difficulty": difficulty[:, None]}

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        """Reset all trucks, or only those flagged by ``tensordict["_reset"]`` (``[N, 1]`` bool).

        Freshly drawn episodes pass through :meth:`Task.on_reset` with their difficulty (a
        task's start curriculum); a state given to :meth:`set_state` starts as it is.

        On a partial reset only the reset rows of the returned tensordict are meaningful: TorchRL
        merges them with ``where(_reset, new, old)``, so the other rows are left at zero and the
        observation (LiDAR included) is the reset trucks' alone (see :meth:`_restart`).
        ``step_and_maybe_reset`` (what rollouts and collectors call) does not come here: it
        restarts the trucks itself (:mod:`truckrl.env.autoreset`).
        """
        reset = None if tensordict is None else tensordict.get("_reset", None)
        n = self.num_envs
        if self._restore is not None or self._state is None or reset is None:
            if self._restore is not None:
                self._state, self._restore = self._restore, None
                self._idle = ()  # a given state may hold anything
            else:
                self._idle = self.task.idle_keys(self._host_difficulty)
                fresh = self._as_tensordict(self._pool.take(n, self._pool_key())[0], n)
                # fresh storage, not slices of the pool: the compiled step guards on the storage
                # offsets of the state it reads
                self._state = fresh.clone()
            if self._scene is not None:
                self._scene.update(self._state["segments"], self._state["mask"])
            cols = dict(self._observe_fn(self._flat_state(), self._difficulty))
        else:
            idx = reset.reshape(n).nonzero().squeeze(-1)  # one sync per reset call
            # plain tensors and per-leaf index_put_ (same values as Composite.zero() and
            # TensorDict indexing, without building TensorDicts)
            cols = {
                k: torch.zeros(shape, dtype=dt, device=self.device)
                for k, shape, dt in self._obs_zero
            }
            if idx.numel():
                for k, v in self._restart(idx).items():
                    cols[k].index_put_((idx,), v)
        # Reward terms 0 and flags / done signals False at the start of an episode; one
        # TensorDict built once (each update() on a TensorDict validates every entry).
        false_col = torch.zeros(n, 1, dtype=torch.bool, device=self.device)
        cols.update({k: torch.zeros(n, 1, device=self.device) for k in self.task.reward_keys})
        cols.update({k: false_col for k in FLAG_KEYS})
        cols.update(done=false_col, terminated=false_col, truncated=false_col)
        return TensorDict(cols, batch_size=[n], device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict["action"]
        if self.config.nonfinite_action == "error":
            finite = torch.isfinite(action).all(-1)
            if not bool(finite.all()):
                bad = (~finite).nonzero().squeeze(-1).tolist()
                raise ValueError(f"non-finite action for env(s) {bad}: {action[~finite].tolist()}")
        new, out = self._transition_fn(action, self._flat_state(), self._difficulty)
        self._state.update(new)
        return TensorDict(out, batch_size=[self.num_envs], device=self.device)
