"""``checkpoint=pretrained[:TASK]``: resolution, errors, where outputs go; the shipped policy."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.golden.golden import CLAIMED_DIFFICULTY, OUTCOME_EPISODES
from truckrl.rl import checkpoint as ckpt
from truckrl.rl.session import run_dir_of


@pytest.fixture
def shipped(tiny_checkpoint, tmp_path, monkeypatch):
    """A tasks dir with one shipped policy, ``parking/pretrained.pt`` (the tiny checkpoint)."""
    run, _, _ = tiny_checkpoint
    folder = tmp_path / "tasks" / "parking"
    folder.mkdir(parents=True)
    shutil.copy(run / "checkpoints" / "last.pt", folder / "pretrained.pt")
    monkeypatch.setattr(ckpt, "TASKS_DIR", folder.parent)
    monkeypatch.setattr(ckpt, "DEFAULT_TASK", "parking")
    return folder


def test_pretrained_names_resolve_to_the_shipped_file(shipped):
    assert ckpt.resolve_checkpoint("pretrained") == shipped / "pretrained.pt"
    assert ckpt.resolve_checkpoint("pretrained:parking") == shipped / "pretrained.pt"
    assert ckpt.pretrained_names() == ["parking"]
    state = ckpt.load_training_state("pretrained:parking")
    assert state["counters"]["iteration"] == 3


def test_unknown_pretrained_name_is_one_line(shipped):
    with pytest.raises(
        ckpt.CheckpointError, match=r"no shipped policy 'dock' \(shipped: \['parking'\]\)"
    ):
        ckpt.resolve_checkpoint("pretrained:dock")


def test_a_path_named_pretrained_wins(shipped, tmp_path, monkeypatch, tiny_checkpoint):
    run, _, _ = tiny_checkpoint
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    shutil.copytree(run, tmp_path / "cwd" / "pretrained")  # a run dir called "pretrained"
    assert ckpt.resolve_checkpoint("pretrained") == Path("pretrained/checkpoints/last.pt")


def test_outputs_of_a_shipped_policy_stay_out_of_the_package(shipped):
    assert run_dir_of(shipped / "pretrained.pt") == Path("outputs/pretrained/parking")
    assert run_dir_of(Path("/x/run/checkpoints/last.pt")) == Path("/x/run")


#: The shipped policies' tasks (each folder holds ``pretrained.pt`` and its card
#: ``pretrained.md``).
TASKS = tuple(sorted(CLAIMED_DIFFICULTY))


def card_claim(task: str) -> tuple[float, float]:
    """``(success rate, difficulty)`` that ``truckrl/tasks/<task>/pretrained.md`` claims: the
    first column (seed 12345) of its table's **all** row, and the difficulty its "How well it
    drives" section names."""
    import re

    import truckrl

    text = (Path(truckrl.__file__).parent / "tasks" / task / "pretrained.md").read_text()
    rate = re.search(r"^\| \*\*all\*\* \| \*\*([0-9.]+) %", text, re.M)
    level = re.search(r"held-out scenes per scene seed, at\s+difficulty ([0-9.]+) \(", text)
    assert rate and level, f"{task}/pretrained.md: no 'all' row or no claimed difficulty"
    return float(rate.group(1)) / 100, float(level.group(1))


def binomial_floor(p: float, n: int = OUTCOME_EPISODES, alpha: float = 0.005) -> int:
    """The highest count ``k`` with ``P(X < k) <= alpha`` for ``X ~ Binomial(n, p)``: were the
    ``n`` scenes a fresh sample, a policy at the claimed rate ``p`` scores below ``k`` with
    probability at most ``alpha``, while one several points worse falls below it."""
    below, k = 0.0, 0
    while k < n and below + math.comb(n, k) * p**k * (1 - p) ** (n - k) <= alpha:
        below += math.comb(n, k) * p**k * (1 - p) ** (n - k)
        k += 1
    return k


def test_the_binomial_floor_matches_hand_computed_tails():
    """P(X < 92) = 0.20 % and P(X < 93) = 0.72 % at p = 0.972; P(X < 73) = 0.35 % and
    P(X < 74) = 0.69 % at p = 0.832 (the tails summed by hand from the pmf)."""
    assert binomial_floor(0.972) == 92
    assert binomial_floor(0.832) == 73
    assert binomial_floor(1.0) == 100 and binomial_floor(0.0) == 0


def test_every_card_claims_the_difficulty_its_outcomes_are_recorded_at():
    for task in TASKS:
        assert card_claim(task)[1] == CLAIMED_DIFFICULTY[task], task


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    """A folder with :func:`~tests.golden.golden.golden_outcomes` of every shipped policy, made
    afresh in ONE subprocess under ``PINNED_ENV`` (scalar kernels, one thread: the same bits on
    every CPU); one interpreter start instead of one per task."""
    from tests.golden.golden import record_pinned

    out = tmp_path_factory.mktemp("outcomes")
    record_pinned(out, "--outcomes", *TASKS)
    return out


@pytest.fixture(params=TASKS)
def played(request, recordings) -> tuple[str, dict]:
    """``(task, fresh recording)`` of the shipped policy of ``task`` (from :func:`recordings`)."""
    from tests.golden.golden import OUTCOME_FILES, load_golden

    task = request.param
    return task, load_golden(recordings / OUTCOME_FILES[task].name)


def test_the_shipped_policy_reaches_its_claimed_level(played):
    """``truckrl eval checkpoint=pretrained:<task> difficulty=<claimed> episodes=100``: at least
    :func:`binomial_floor` of the card's claimed rate in successes (a wrong, broken or worse
    file fails here, and so does a card that claims more than its file does)."""
    task, fresh = played
    claim, difficulty = card_claim(task)
    floor = binomial_floor(claim)
    successes = int((fresh["outcome"] & 1).sum())
    assert fresh["difficulty"] == difficulty
    assert successes >= floor, (
        f"shipped {task} policy: {successes} of {OUTCOME_EPISODES} successes at difficulty "
        f"{difficulty:g}, below the floor {floor} (its model card claims {claim:.1%})"
    )


def test_the_shipped_policy_ends_every_episode_as_recorded(played):
    """Each of the 100 episodes ends as ``tests/golden/outcomes_<task>.npz`` recorded (success,
    collision, jackknife or timeout), at the recorded tolerances: a change of the simulator, the
    task or the evaluation that flips an outcome shows here, naming the episodes."""
    from tests.golden.golden import OUTCOME_FILES, load_golden
    from truckrl.tasks import OUTCOMES

    task, fresh = played
    golden = load_golden(OUTCOME_FILES[task])
    assert sorted(fresh) == sorted(golden), "the set of recorded keys changed"
    np.testing.assert_array_equal(fresh["tolerance"], golden["tolerance"], err_msg="tolerance")
    np.testing.assert_array_equal(fresh["difficulty"], golden["difficulty"], err_msg="difficulty")

    def name(code: int) -> str:
        return "+".join(o.name for i, o in enumerate(OUTCOMES) if code >> i & 1) or "none"

    flipped = np.flatnonzero(fresh["outcome"] != golden["outcome"])
    changes = ", ".join(
        f"{i}: {name(golden['outcome'][i])} -> {name(fresh['outcome'][i])}" for i in flipped
    )
    assert not flipped.size, (
        f"shipped {task} policy: {flipped.size} of 100 episodes end otherwise than recorded "
        f"(episode: recorded -> now): {changes}. If the change is meant to alter outcomes, "
        f"re-record with `python -m tests.golden.golden --outcomes {task}` and say why in the "
        "commit message"
    )


def test_the_shipped_policies_are_the_tasks_their_cards_name():
    from truckrl.rl.policy import load_policy

    assert sorted(ckpt.pretrained_names()) == sorted(CLAIMED_DIFFICULTY)
    for task, difficulty in CLAIMED_DIFFICULTY.items():
        policy = load_policy(f"pretrained:{task}")
        assert policy.env_config.task.name == task
        assert policy.difficulty == difficulty, task  # its curriculum's, where it was kept
    assert load_policy("pretrained:uturn").env_config.task.observe_route


def test_retired_config_fields_load_or_say_what_was_removed():
    """A saved config from before a field was removed loads without it when its value is what
    the code does now, and is one line naming the field when it is not."""
    import yaml

    from truckrl.rl.checkpoint import CheckpointError
    from truckrl.rl.policy import saved_config

    def state(env: dict) -> dict:
        return {"config": yaml.safe_dump({"env": env, "train_env": {}}), "path": "old.pt"}

    old = {"lidar": {"num_beams": 16, "method": "dense"}, "task": {"name": "x", "reach_slack": 2}}
    assert saved_config(state(old))["env"] == {"lidar": {"num_beams": 16}, "task": {"name": "x"}}
    with pytest.raises(CheckpointError, match=r"old.pt: env.lidar.method = 'span' was removed"):
        saved_config(state({"lidar": {"method": "span"}}))
