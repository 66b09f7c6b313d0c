"""InPlaceAutoReset: TorchRL's ``step_and_maybe_reset`` with restarted rows written into the root.

Every use of TorchRL's private API by truckrl is in this module. It was read against torchrl
0.14.1 (``torchrl/envs/common.py``; the project requires ``torchrl>=0.14.1``), and
``tests/env/test_autoreset.py`` fails if a later version drops what it relies on or if the
outputs stop matching TorchRL's own path:

* ``EnvBase._step_and_maybe_reset`` is overridden: the public ``step_and_maybe_reset`` (called by
  ``rollout``, collectors and ``ParallelEnv`` workers) and ``EnvBase.compile`` call it.
* ``EnvBase._post_step_mdp_hooks`` (``None`` unless a transform sets one) and the instance flag
  ``_torchrl_native_autoreset`` (set by TorchRL's gym and mjlab wrappers): when either is set,
  TorchRL's own path runs, since this one implements neither.

What it buys: TorchRL's path (``maybe_reset`` -> ``reset(select_reset_only=True)`` -> ``_reset``
-> ``where``-merge over every key) builds a full-size reset tensordict of zeros and merges it key
by key; here each observation leaf of the root is copied once, the restarted rows are written
into it, and the restarted trucks' first observation can come ready-made from an episode pool.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase


class InPlaceAutoReset:
    """Mixin for a batched ``EnvBase`` (list it before ``EnvBase``) of ``batch_size=[N]`` with one
    ``done`` ``[N, 1]`` at the root.

    The subclass provides ``_restart`` and ``_reset_zero_keys``, the same contract as its
    ``_reset`` on a partial reset. The root that ``_step_and_maybe_reset`` returns is what
    TorchRL's merge gives, bit for bit: the restarted rows of each observation leaf from
    ``_restart``; zeros on the restarted rows for the keys in ``_reset_zero_keys``; and
    for anything else at the root (the action, a policy's outputs) zeros on those rows too when
    only some trucks restart (the merge's zero padding), but the old values when all of them do
    (TorchRL then updates the root instead of merging).
    """

    #: Root leaves that a reset sets to zero / ``False``: reward terms, flags and done signals.
    _reset_zero_keys: frozenset[str]

    def _restart(self, idx: torch.Tensor) -> dict[str, torch.Tensor]:
        """Start fresh episodes for the rows ``idx`` (``[m]`` int64, ``m >= 1``) and return their
        first observation ``{key: [m, ...]}`` (every observation leaf)."""
        raise NotImplementedError

    def _step_and_maybe_reset(
        self, tensordict: TensorDictBase
    ) -> tuple[TensorDictBase, TensorDictBase]:
        """One step, then fresh episodes for the rows it ended (see the class docstring)."""
        if self._post_step_mdp_hooks is not None or self.__dict__.get(
            "_torchrl_native_autoreset", False
        ):
            return super()._step_and_maybe_reset(tensordict)
        if tensordict.device != self.device:
            tensordict = tensordict.to(self.device)
        tensordict = self.step(tensordict)
        root = self.step_mdp(tensordict)
        ended = root.get("done").reshape(-1)
        idx = ended.nonzero().squeeze(-1)  # one sync per step, as TorchRL's any_done
        if idx.numel():
            obs = self._restart(idx)
            every = idx.numel() == ended.numel()
            for key, value in list(root.items(include_nested=True, leaves_only=True)):
                if key in obs:  # copy: the old tensor is also the transition's "next" entry
                    new = value.clone()
                    new.index_put_((idx,), obs[key])
                elif isinstance(value, torch.Tensor) and (
                    key in self._reset_zero_keys or not every
                ):
                    new = value.masked_fill(ended.view(-1, *(1,) * (value.ndim - 1)), 0)
                else:  # every row restarts: TorchRL keeps the other root entries as they are
                    continue
                root.set(key, new)
        return tensordict, root
