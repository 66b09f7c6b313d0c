"""PPO on TorchRL: GAE, the clipped loss, Adam with gradient clipping and the adaptive KL schedule.

The paper trained with RSL-RL's PPO (section "PPO and Learning setup"); this module reproduces its
update on TorchRL parts: :class:`~torchrl.objectives.value.GAE` for advantages,
:class:`~torchrl.objectives.ClipPPOLoss` for the loss, advantages normalised over the whole batch,
and RSL-RL's adaptive learning rate (:class:`AdaptiveKLSchedule`) driven by the analytic KL
between the rollout policy and the current one, checked before every minibatch step.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from truckrl.rl.config import PPOConfig
from truckrl.rl.imitation import action_mse
from truckrl.rl.network import HIDDEN_KEY, LIDAR_KEY, OBS_KEY, ActorCritic


class AdaptiveKLSchedule:
    """RSL-RL's adaptive learning rate: keep the per-update KL near a target.

    ``lr /= factor`` when ``kl > 2 * desired_kl``; ``lr *= factor`` when ``kl < desired_kl / 2``;
    otherwise unchanged; always clamped to ``[lr_min, lr_max]``.
    """

    def __init__(
        self,
        lr: float,
        desired_kl: float = 0.01,  # paper: KL target 0.01
        lr_min: float = 1e-5,
        lr_max: float = 1e-2,
        factor: float = 1.5,  # RSL-RL
    ) -> None:
        self.lr = float(lr)
        self.desired_kl = desired_kl
        self.lr_min = lr_min
        self.lr_max = lr_max
        self.factor = factor

    def step(self, kl: float) -> float:
        """Update from one measured KL (a Python float) and return the new learning rate."""
        if kl > 2.0 * self.desired_kl:
            self.lr = self.lr / self.factor
        elif kl < 0.5 * self.desired_kl:
            self.lr = self.lr * self.factor
        self.lr = min(max(self.lr, self.lr_min), self.lr_max)
        return self.lr


def gaussian_kl(loc0: Tensor, scale0: Tensor, loc1: Tensor, scale1: Tensor) -> Tensor:
    """KL(N0 || N1) of diagonal Gaussians, summed over the last (action) dim.

    Args:
        loc0, scale0: ``[*B, A]`` old policy mean and std.
        loc1, scale1: ``[*B, A]`` new policy mean and std.

    Returns:
        ``[*B]`` KL in nats.
    """
    kl = (
        torch.log(scale1 / scale0)
        + (scale0.square() + (loc0 - loc1).square()) / (2.0 * scale1.square())
        - 0.5
    )
    return kl.sum(-1)


#: What one minibatch step reads: the actor/critic inputs, the rollout's action, log-prob and
#: Gaussian (for the ratio and the KL), and GAE's outputs.
_UPDATE_KEYS = (OBS_KEY, LIDAR_KEY, "action", "action_log_prob", "loc", "scale")
_UPDATE_KEYS += ("advantage", "value_target", "state_value")
#: The loss entries :meth:`PPO.update` averages over its minibatches and returns.
_LOSS_STATS = ("loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx")
_LOSS_STATS += ("clip_fraction",)


class _ClipPPOLoss(ClipPPOLoss):
    """ClipPPOLoss that keeps the current policy's mean and std of its last forward.

    The adaptive learning rate needs KL(rollout policy || current policy) on each minibatch; taking
    the current Gaussian from the loss's own actor pass saves a second trunk forward per minibatch.

    The entropy is the Gaussian's closed form, always: TorchRL's own choice is the same in eager
    mode, but under ``torch.compile`` it also draws a Monte-Carlo estimate (to stand in for a
    non-finite one), which would spend random numbers and so change the minibatch shuffles.
    """

    last_loc: Tensor | None = None
    last_scale: Tensor | None = None

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # TorchRL keeps the value-clip radius as a 0-d tensor buffer and branches on its truth
        # ("if self.clip_value:"), which breaks a compiled graph in two; a Python float (or None)
        # is the same number and branches at trace time
        clip = self._buffers.pop("clip_value", None)
        self.clip_value = None if clip is None else float(clip)

    def _log_weight(self, tensordict, adv_shape):
        out = super()._log_weight(tensordict, adv_shape)
        dist = out[1]
        self.last_loc, self.last_scale = dist.mean.detach(), dist.stddev.detach()
        return out

    def _get_entropy(self, dist, adv_shape):
        return dist.entropy().unsqueeze(-1)  # IndependentNormal: [*B] -> [*B, 1]


@contextlib.contextmanager
def _span(timings: dict[str, float] | None, key: str, device: torch.device) -> Iterator[None]:
    """Add the wall time [s] of the ``with`` body to ``timings[key]`` (no-op when ``None``).

    On CUDA the device is synchronised at both ends, so the span holds the kernels it launched.
    """
    if timings is None:
        yield
        return
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda _device: None)
    sync(device)
    t0 = time.perf_counter()
    yield
    sync(device)
    timings[key] = timings.get(key, 0.0) + time.perf_counter() - t0


#: The parts of :meth:`PPO.update` its ``timings`` argument receives [s].
UPDATE_SPANS = ("gae", "loss_forward", "backward", "optimizer", "metrics")


def _take_rows(td: TensorDictBase, index: Tensor) -> TensorDictBase:
    """``td[index]`` for a 1-D long ``index`` ``[K]`` into dim 0 of a ``[N]`` tensordict.

    One ``index_select`` per entry: the same rows as advanced indexing (``td[index]``), which is
    slower on a CPU for large batches.
    """
    return td.apply(lambda t: t.index_select(0, index), batch_size=index.shape)


def _continues(batch: TensorDictBase, nxt: TensorDictBase, ends: Tensor) -> bool:
    """Whether each step's next observation is the following step's observation, except at ``ends``.

    ``batch`` and ``nxt`` are ``[..., T]`` (time last), ``ends`` ``[..., T]`` bool. True for
    collector output; costs one comparison of the observations (a host sync, in the update).
    """
    ok = ends[..., :-1].clone()  # across an episode end anything goes
    same = torch.ones_like(ok)
    for key in (OBS_KEY, LIDAR_KEY):
        same &= (batch.get(key)[..., 1:, :] == nxt.get(key)[..., :-1, :]).all(-1)
    return bool((ok | same).all())


class PPO:
    """One PPO learner: call :meth:`update` with each collected batch.

    Args:
        ac: the actor-critic (its trunk is shared by actor and critic).
        cfg: hyper-parameters.
    """

    #: Demonstration samples ``[M]`` ("observation", "lidar", "action") for the cloning term, or
    #: None; with ``bc_coeff > 0`` every minibatch adds ``bc_coeff`` x the actor's action MSE on
    #: ``bc_batch`` of them drawn at random (``demos.bc_coeff``; the trainer sets the weight each
    #: iteration); ``bc_executed``: the error of the mean as the env executes it
    #: (``demos.bc_loss``, ``truckrl.rl.imitation.action_mse``).
    demos: TensorDictBase | None = None
    bc_coeff: float = 0.0
    bc_batch: int = 1024
    bc_executed: bool = False

    def __init__(self, ac: ActorCritic, cfg: PPOConfig) -> None:
        self.ac = ac
        self.cfg = cfg
        # no value network: compute_advantages supplies both value entries (see there)
        self.gae = GAE(gamma=cfg.gamma, lmbda=cfg.lmbda, value_network=None, average_gae=False)
        # The critic is the value head alone: the actor pass inside the loss already wrote a
        # differentiable "hidden", so the shared trunk runs once per minibatch and still gets
        # gradients from both losses.
        self.loss = _ClipPPOLoss(
            ac.actor,
            ac.value_head,
            clip_epsilon=cfg.clip_epsilon,
            entropy_coeff=cfg.entropy_coeff,
            critic_coeff=cfg.value_coeff,
            loss_critic_type=cfg.loss_critic_type,
            normalize_advantage=False,
            clip_value=cfg.clip_epsilon if cfg.clip_value else None,
            # the modules' own parameters (no target networks here): the same numbers without
            # swapping a parameter copy into the modules on every call
            functional=False,
        )
        # ppo.compile: one graph for the loss's forward and backward; the same minibatch size
        # every step, so it compiles once (twice with the cloning term on and off)
        self._objective = (
            torch.compile(self._minibatch_objective, dynamic=False)
            if cfg.compile
            else self._minibatch_objective
        )
        # foreach: one kernel per op for all parameters instead of one per parameter (the CPU
        # default is the per-parameter loop); same arithmetic, bit for bit, less step time
        self.optimizer = torch.optim.Adam(ac.model.parameters(), lr=cfg.lr, foreach=True)
        self.schedule = (
            AdaptiveKLSchedule(cfg.lr, cfg.desired_kl, cfg.lr_min, cfg.lr_max)
            if cfg.lr_schedule == "adaptive"
            else None
        )

    @property
    def lr(self) -> float:
        return float(self.optimizer.param_groups[0]["lr"])

    def set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        if self.schedule is not None:
            self.schedule.lr = lr

    @torch.no_grad()
    def compute_advantages(self, batch: TensorDictBase) -> TensorDictBase:
        """Add "advantage", "value_target" and "state_value" to a ``[..., T]`` rollout (time last).

        The critic's values of the collected observations come from the batch when the collector
        ran :attr:`ActorCritic.rollout_policy <truckrl.rl.network.ActorCritic.rollout_policy>`
        (the same weights: the update has not started yet); otherwise the critic runs over the
        batch once. The value of each step's next observation is the next step's value, except
        where the episode ended (the next observation is the terminal one, not the reset one) and
        at the last step of each row: only those observations go through the critic (about
        ``1/T`` of the batch plus the episode ends, instead of the whole batch twice). A batch
        whose rows are not trajectories (a next observation differs from the following step's
        observation within an episode) gets the critic on every next observation instead.
        """
        batch = batch.exclude(HIDDEN_KEY, ("next", HIDDEN_KEY))
        value = batch.get("state_value", None)
        if value is None:  # collected by the actor alone
            value = self._values(batch)
            batch.set("state_value", value)
        # steps whose next observation is not the next step's observation: [..., T]
        ends = batch.get(("next", "done")).squeeze(-1).clone()
        ends[..., -1] = True
        nxt = batch.get("next")
        if not _continues(batch, nxt, ends):  # not one trajectory per row: no shortcut
            ends = torch.ones_like(ends)
        next_value = torch.empty_like(value)
        next_value[..., :-1, :] = value[..., 1:, :]
        next_value[ends] = self._values(nxt[ends])
        batch.set(("next", "state_value"), next_value)
        self.gae(batch)
        if self.cfg.normalize_advantage:
            adv = batch["advantage"]
            batch["advantage"] = (adv - adv.mean()) / (adv.std() + 1e-8)
        return batch

    def _minibatch_objective(
        self, mb: TensorDictBase, demos: TensorDictBase | None, bc_coeff: Tensor
    ) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """The loss of one minibatch step and what the update logs of it.

        Args:
            mb: ``[M]`` minibatch with the :data:`_UPDATE_KEYS`.
            demos: ``[K]`` demonstration samples for the cloning term, or None.
            bc_coeff: ``[]`` weight of the cloning term.

        Returns:
            ``(total [], stats [len(_LOSS_STATS)], kl [], bc [] or None)``: the differentiable
            total loss, the loss's logged entries (detached, in :data:`_LOSS_STATS` order), the
            analytic KL(rollout policy || current policy) averaged over the minibatch, and the
            cloning term's action MSE before its weight.
        """
        out = self.loss(mb)
        total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
        bc = None
        if demos is not None:  # keep the demonstrated actions (demos.bc_coeff)
            bc = action_mse(self.ac, demos, self.bc_executed)
            total = total + bc_coeff * bc
            bc = bc.detach()
        stats = torch.stack([out[k].detach() for k in _LOSS_STATS])
        kl = gaussian_kl(mb["loc"], mb["scale"], self.loss.last_loc, self.loss.last_scale).mean()
        return total, stats, kl, bc

    def _values(self, td: TensorDictBase) -> Tensor:
        """Critic values ``[*B, 1]`` of the observations in ``td`` (``[*B]``), without grad."""
        return self.ac.critic(td.select(OBS_KEY, LIDAR_KEY))["state_value"]

    def _minibatch_step(
        self,
        shuffled: TensorDictBase,
        rows: slice,
        demos: TensorDictBase | None,
        bc_coeff: Tensor,
        params: list[Tensor],
        timings: dict[str, float] | None,
        dev: torch.device,
    ) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """One gradient step on the minibatch ``shuffled[rows]`` (with ``bc_batch`` demonstration
        rows drawn from ``demos`` when given), timed into ``timings`` as :meth:`update` says
        (synchronising ``dev``).

        Returns:
            The minibatch's loss entries and KL (:meth:`_objective`), the gradient norm before
            clipping, and the cloning term's action MSE (``None`` without demonstrations).
        """
        with _span(timings, "loss_forward", dev):
            mb = shuffled[rows]
            picked = None
            if demos is not None:
                pick = torch.randint(demos.numel(), (self.bc_batch,), device=demos.device)
                picked = _take_rows(demos, pick)
            # the KL of this minibatch before the step comes from the loss's own forward
            # (RSL-RL order: the new learning rate applies to this very step)
            total, stats, kl, bc = self._objective(mb, picked, bc_coeff)
        with _span(timings, "optimizer", dev):
            if self.schedule is not None:
                self.set_lr(self.schedule.step(kl.item()))
            self.optimizer.zero_grad(set_to_none=True)
        with _span(timings, "backward", dev):
            total.backward()
        with _span(timings, "optimizer", dev):
            grad_norm = torch.nn.utils.clip_grad_norm_(params, self.cfg.max_grad_norm)
            self.optimizer.step()
            self.ac.gaussian.project_()
        return stats, kl, grad_norm, bc

    def update(
        self, batch: TensorDictBase, timings: dict[str, float] | None = None
    ) -> dict[str, float]:
        """Run ``num_epochs`` x ``num_minibatches`` gradient steps on one rollout.

        Args:
            batch: collector output ``[..., T]`` with "observation", "lidar", "action", "loc",
                "scale", "action_log_prob" and the ("next", ...) step entries.
            timings: optional dict that receives the wall time [s] of each part, summed over the
                minibatches (:data:`UPDATE_SPANS`): "gae" (advantages, flattening and key
                selection), "loss_forward" (minibatch indexing, loss and KL), "backward",
                "optimizer" (learning-rate schedule, gradient clipping, Adam step) and "metrics"
                (the sums and the final read-out). Synchronised on CUDA; the numbers computed are
                the same with or without it (``truckrl bench train`` reads it).

        Returns:
            Means over all minibatches: "loss_objective", "loss_critic", "loss_entropy",
            "entropy", "kl" (analytic, old || new), "kl_approx" (TorchRL's sample estimate),
            "clip_fraction", "grad_norm", and "loss_bc" (the cloning term's action MSE, before
            its weight) when it is on; plus "lr" (after the update), "action_std" (mean over
            the action axes) and "action_std_longitudinal" / "action_std_lateral" (each axis:
            the mean hides one axis growing while the other shrinks).
        """
        dev = batch.device if batch.device is not None else torch.device("cpu")
        with _span(timings, "gae", dev):
            # only what the loss and the KL read: every collected key would be indexed per
            # minibatch
            batch = self.compute_advantages(batch).reshape(-1).select(*_UPDATE_KEYS)
        n = batch.numel()
        mb_size = self.cfg.check_batch(n)
        stat_sums = torch.zeros(len(_LOSS_STATS), device=batch.device)
        sums = {k: torch.zeros((), device=batch.device) for k in ("kl", "grad_norm")}
        demos = self.demos if self.bc_coeff > 0 and self.demos is not None else None
        if demos is not None:
            sums["loss_bc"] = torch.zeros((), device=batch.device)
        bc_coeff = torch.tensor(self.bc_coeff, device=batch.device)
        params = list(self.ac.model.parameters())
        steps = 0
        for _ in range(self.cfg.num_epochs):
            perm = torch.randperm(n, device=batch.device)
            with _span(timings, "loss_forward", dev):
                # one gather per epoch, then contiguous minibatch views: the same rows as
                # indexing per minibatch, with one indexing call per key instead of one per step
                shuffled = _take_rows(batch, perm)
            for start in range(0, n, mb_size):
                stats, kl, grad_norm, bc = self._minibatch_step(
                    shuffled, slice(start, start + mb_size), demos, bc_coeff, params, timings, dev
                )
                with _span(timings, "metrics", dev):
                    stat_sums += stats
                    sums["kl"] += kl
                    sums["grad_norm"] += grad_norm.detach()
                    if bc is not None:
                        sums["loss_bc"] += bc
                steps += 1
        with _span(timings, "metrics", dev):
            metrics = dict(zip(_LOSS_STATS, (stat_sums / steps).tolist(), strict=True))
            metrics.update({k: v.item() / steps for k, v in sums.items()})
            metrics["lr"] = self.lr
            std = self.ac.action_std().tolist()  # [A]: longitudinal, lateral
            metrics["action_std"] = sum(std) / len(std)
            metrics.update(
                zip(("action_std_longitudinal", "action_std_lateral"), std, strict=False)
            )
        return metrics

    def state_dict(self) -> dict:
        return {"optimizer": self.optimizer.state_dict(), "lr": self.lr}

    def load_state_dict(self, state: dict) -> None:
        self.optimizer.load_state_dict(state["optimizer"])
        for group in self.optimizer.param_groups:  # a checkpoint's own choice (None in older ones)
            group["foreach"] = True
        self.set_lr(float(state["lr"]))
