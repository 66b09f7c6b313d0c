"""truckrl.env.autoreset: the TorchRL private API it relies on is still there, and its in-place
auto-reset gives TorchRL's own ``step_and_maybe_reset`` outputs bit for bit.

The independent answer is TorchRL's stock path (``EnvBase._step_and_maybe_reset``: ``maybe_reset``
-> ``reset`` -> ``_reset`` -> ``where``-merge with zero padding) on a second env of the same seed.
"""

import inspect
import types

import pytest
import torch
from torchrl.envs import EnvBase

from truckrl.env import TruckEnv
from truckrl.env.autoreset import InPlaceAutoReset

#: (config, difficulty, which restarts must occur). The intersection task keeps drawn episodes
#: as they are (the pool holds their first observation); the dock task moves the start by
#: difficulty (its start curriculum), so its observation is computed at the reset. TorchRL zeroes
#: the other root entries (the action, a policy's outputs) on the restarted rows when some trucks
#: restart, and keeps them when all do; both cases are covered. Random dock trucks rarely crash:
#: they all time out together.
CASES = pytest.mark.parametrize(
    "cfg,difficulty,case",
    [
        ({"max_steps": 6}, 0.0, "some"),
        ({"max_steps": 3}, 0.0, "all"),  # every truck times out on the same step
        ({"task": {"name": "dock"}, "max_steps": 12}, 2.0, "all"),
    ],
    ids=["intersection", "all-at-once", "dock"],
)


def pair(n, cfg, difficulty):
    """Two envs of one seed: the first with the in-place auto-reset, the second with it switched
    off (TorchRL's stock ``_step_and_maybe_reset`` bound on the instance)."""
    fast, stock = (TruckEnv(num_envs=n, config=cfg, seed=5) for _ in range(2))
    stock._step_and_maybe_reset = types.MethodType(EnvBase._step_and_maybe_reset, stock)
    for env in (fast, stock):
        env.set_difficulty(difficulty)
    return fast, stock


def test_torchrl_private_api_still_there():
    env = TruckEnv(num_envs=2, seed=0)
    # the override is what the public entry points call
    assert type(env)._step_and_maybe_reset is InPlaceAutoReset._step_and_maybe_reset
    assert callable(EnvBase.__dict__["_step_and_maybe_reset"])
    assert "self._step_and_maybe_reset(" in inspect.getsource(EnvBase.step_and_maybe_reset)
    assert "self._step_and_maybe_reset" in inspect.getsource(EnvBase.compile)
    # the conditions under which TorchRL's own path must run instead
    assert "_post_step_mdp_hooks" in vars(EnvBase) and env._post_step_mdp_hooks is None
    stock = inspect.getsource(EnvBase._step_and_maybe_reset)
    assert "self._post_step_mdp_hooks" in stock
    assert 'self.__dict__.get("_torchrl_native_autoreset"' in stock
    assert "_torchrl_native_autoreset" not in env.__dict__
    assert callable(env.step_mdp)  # public API the override uses


def test_post_step_hook_falls_back_to_torchrl_path(monkeypatch):
    calls = []
    stock = EnvBase._step_and_maybe_reset

    def spy(self, td):
        calls.append(td)
        return stock(self, td)

    monkeypatch.setattr(EnvBase, "_step_and_maybe_reset", spy)
    env = TruckEnv(num_envs=3, seed=0)
    td = env.reset().set("action", torch.zeros(3, 2))
    env.step_and_maybe_reset(td)
    assert not calls
    env._post_step_mdp_hooks = lambda data, data_: (data, data_.set("hooked", data_["done"]))
    _, root = env.step_and_maybe_reset(td)
    assert len(calls) == 1 and "hooked" in root.keys()


class CarryPolicy:
    """A random action (a NaN row each step, zeroed at a restart like any other) and a
    ``("policy", "hidden")`` entry computed from the one it finds at the root, as a recurrent
    policy's state: what the merge leaves on restarted rows feeds the next outputs."""

    def __init__(self, n):
        self.n, self.step, self.gen = n, 0, torch.Generator().manual_seed(3)

    def __call__(self, td):
        action = torch.rand(self.n, 2, generator=self.gen) * 2.4 - 1.2
        action[self.step % self.n] = float("nan")
        self.step += 1
        old = td.get(("policy", "hidden"), torch.zeros(self.n, 3))
        hidden = 0.5 * old + torch.rand(self.n, 3, generator=self.gen) + 1
        return td.set("action", action).set(("policy", "hidden"), hidden)


@CASES
def test_rollout_equals_torchrl_stock_path(cfg, difficulty, case):
    n = 24
    fast, stock = pair(n, cfg, difficulty)
    out = [
        env.rollout(30, CarryPolicy(n), break_when_any_done=False, auto_reset=True)
        for env in (fast, stock)
    ]
    keys = set(out[0].keys(include_nested=True, leaves_only=True))
    assert keys == set(out[1].keys(include_nested=True, leaves_only=True))
    assert ("policy", "hidden") in keys and "_reset" not in keys
    for key in keys:  # exactly, NaN actions too
        torch.testing.assert_close(out[0][key], out[1][key], rtol=0, atol=0, equal_nan=True)
    assert out[0].batch_size == (n, 30)  # rollouts stack time last
    ended = out[0]["next", "done"].squeeze(-1)[:, :-1].T  # [step, truck]; no reset after the last
    some = (ended.any(-1) & ~ended.all(-1)).any()
    assert bool(some if case == "some" else ended.all(-1).any())


@CASES
def test_step_and_maybe_reset_equals_torchrl_stock_path(cfg, difficulty, case):
    # step by step, with the hand-written expectations of the merge beside the comparison
    n = 24
    fast, stock = pair(n, cfg, difficulty)
    td_f, td_g = fast.reset(), stock.reset()
    gen = torch.Generator().manual_seed(3)
    seen = {"some": 0, "all": 0}
    for step in range(30):
        action = torch.rand(n, 2, generator=gen) * 2.4 - 1.2
        action[step % n] = float("nan")
        extra = torch.rand(n, 3, generator=gen) + 1  # something a policy left at the root
        for td in (td_f, td_g):
            td.set("action", action)
            td.set(("policy", "hidden"), extra.clone())
        out_f, td_f = fast.step_and_maybe_reset(td_f)
        out_g, td_g = stock.step_and_maybe_reset(td_g)
        keys_f = set(td_f.keys(include_nested=True, leaves_only=True))
        assert keys_f == set(td_g.keys(include_nested=True, leaves_only=True))
        assert "_reset" not in keys_f
        for key in out_g.keys(include_nested=True, leaves_only=True):
            torch.testing.assert_close(out_f[key], out_g[key], rtol=0, atol=0, equal_nan=True)
        for key in keys_f:
            torch.testing.assert_close(td_f[key], td_g[key], rtol=0, atol=0, equal_nan=True)
        ended = out_f["next", "done"].squeeze(-1)
        if ended.any():
            seen["all" if ended.all() else "some"] += 1
        kept = extra if ended.all() else torch.where(ended[:, None], 0.0, extra)
        assert torch.equal(td_f["policy", "hidden"], kept)
        assert not td_f["done"].any() and not td_f["collision"].any()
        assert torch.all(td_f["step_count"][ended] == 0)
    assert seen[case] >= 1
