"""``policy=SPEC`` (``truckrl/rl/policy_specs.py``): parsing, loading, one-line errors, and the
shipped policy against its ONNX export on the same held-out scenes.

ONNX models here are built by hand with ``onnx.helper`` (``action = observation @ A + lidar @
B``), so the expected action is plain numpy, independent of the exporter and of the code under
test.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import textwrap

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from truckrl.config.fields import ConfigError
from truckrl.evaluation.rollout import as_policy, evaluate_policy
from truckrl.rl.policy_specs import (
    PolicySpec,
    base_env,
    parse_policy_spec,
    resolve_policy,
    spec_of,
)
from truckrl.tasks import EnvConfig

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

SMALL_ENV = EnvConfig(max_steps=30)  # intersection: 26 features, 16 beams
NUM_OBS, NUM_BEAMS = 26, 16


def linear_onnx(
    path,
    num_obs: int = NUM_OBS,
    num_beams: int = NUM_BEAMS,
    card: dict | None = None,
    names: tuple[str, str, str] = ("observation", "lidar", "action"),
    width: int = 2,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Write ``action = observation @ A + lidar @ B`` as ONNX; return ``(A, B)``."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    a = (rng.standard_normal((num_obs, width)) * 0.3).astype(np.float32)
    b = (rng.standard_normal((num_beams, width)) * 0.3).astype(np.float32)
    obs, lidar, act = names
    graph = helper.make_graph(
        [
            helper.make_node("MatMul", [obs, "A"], ["oa"]),
            helper.make_node("MatMul", [lidar, "B"], ["lb"]),
            helper.make_node("Add", ["oa", "lb"], [act]),
        ],
        "linear",
        [
            helper.make_tensor_value_info(obs, TensorProto.FLOAT, ["batch", num_obs]),
            helper.make_tensor_value_info(lidar, TensorProto.FLOAT, ["batch", num_beams]),
        ],
        [helper.make_tensor_value_info(act, TensorProto.FLOAT, ["batch", width])],
        [numpy_helper.from_array(a, "A"), numpy_helper.from_array(b, "B")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    if card is not None:
        entry = model.metadata_props.add()
        entry.key, entry.value = "truckrl", json.dumps(card)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return a, b


def card_for(env_cfg: EnvConfig, difficulty: float) -> dict:
    return {"env_config": dataclasses.asdict(env_cfg), "difficulty": difficulty}


# ---------------------------------------------------------------------------------- parsing
@pytest.mark.parametrize(
    ("text", "kind", "target"),
    [
        ("checkpoint:outputs/run", "checkpoint", "outputs/run"),
        ("checkpoint:C:/runs/a.pt", "checkpoint", "C:/runs/a.pt"),
        ("pretrained", "checkpoint", "pretrained"),
        ("pretrained:dock", "checkpoint", "pretrained:dock"),
        ("onnx:export/policy.onnx", "onnx", "export/policy.onnx"),
        ("planner", "planner", ""),
        ("my_pkg.drivers:make", "module", "my_pkg.drivers:make"),
        ("drivers:make_policy", "module", "drivers:make_policy"),
    ],
)
def test_spec_forms(text, kind, target):
    assert parse_policy_spec(text) == PolicySpec(kind, target, text)


@pytest.mark.parametrize(
    "text", ["tflite", "onnx", "checkpoint:", "onnx: ", "outputs/run", "a b:c", "mod:1fn", ":f"]
)
def test_unknown_schemes_are_one_line(text):
    with pytest.raises(ConfigError) as e:
        parse_policy_spec(text)
    msg = str(e.value)
    assert msg.startswith(f"policy = {text.strip()!r}") and "\n" not in msg


def test_checkpoint_field_is_the_short_form():
    assert spec_of(None, None) is None and spec_of("checkpoint", None) is None
    assert spec_of("checkpoint", "runs/a") == PolicySpec(
        "checkpoint", "runs/a", "checkpoint:runs/a"
    )
    assert spec_of(None, "pretrained").target == "pretrained"
    assert spec_of("planner", "runs/a").kind == "planner"  # the checkpoint gives the env
    with pytest.raises(ConfigError, match="give one"):
        spec_of("onnx:p.onnx", "runs/a")


def test_task_of_a_policy_without_env():
    assert base_env({}) == EnvConfig()
    assert base_env({"task": {"name": "dock"}}).task.name == "dock"
    with pytest.raises(ConfigError, match="'nope' is not a task"):
        base_env({"task": {"name": "nope"}})


# ---------------------------------------------------------------------------------- onnx
def test_onnx_policy_is_the_models_action_for_the_whole_batch(tmp_path):
    path = tmp_path / "p.onnx"
    cfg = dataclasses.replace(SMALL_ENV, max_steps=17)
    a, b = linear_onnx(path, card=card_for(cfg, 2.5))
    p = resolve_policy(parse_policy_spec(f"onnx:{path}"), env_config=EnvConfig())
    assert p.env_config == cfg and p.difficulty == 2.5 and p.fixed_env  # the card's, not given
    g = torch.Generator().manual_seed(1)
    obs, lidar = torch.randn(7, NUM_OBS, generator=g), torch.rand(7, NUM_BEAMS, generator=g)
    td = TensorDict({"observation": obs, "lidar": lidar}, batch_size=[7])
    got = p.actor(td)["action"]
    assert got.shape == (7, 2) and got.dtype == torch.float32
    np.testing.assert_allclose(got.numpy(), obs.numpy() @ a + lidar.numpy() @ b, atol=1e-5)


def test_onnx_file_without_model_card_runs_in_the_given_env(tmp_path):
    path = tmp_path / "bare.onnx"
    linear_onnx(path, num_obs=30, num_beams=16)  # dock observes 30 features
    dock = base_env({"task": {"name": "dock"}})
    p = resolve_policy(parse_policy_spec(f"onnx:{path}"), env_config=dock)
    assert p.env_config == dock and p.difficulty is None and not p.fixed_env
    with pytest.raises(ConfigError, match=r"observation is tensor\(float\) \['batch', 30\]"):
        resolve_policy(parse_policy_spec(f"onnx:{path}"))  # the default task observes 26


@pytest.mark.parametrize(
    ("kind", "fragment"),
    [
        ("missing", "file not found"),
        ("text", "is not a readable ONNX model"),
        ("names", "inputs are ['lidar', 'obs'], the env gives ['observation', 'lidar']"),
        ("output", "no output 'action'"),
        ("features", "observation is tensor(float) ['batch', 20], task 'intersection' with 16 "
                     "beams needs tensor(float) [batch, 26]"),
        ("beams", "lidar is tensor(float) ['batch', 32]"),
        ("width", "action is tensor(float) ['batch', 3]"),
    ],
)  # fmt: skip
def test_bad_onnx_files_are_one_line(tmp_path, kind, fragment):
    path = tmp_path / "p.onnx"
    card = card_for(SMALL_ENV, 1.0)
    if kind == "text":
        path.write_text("not a model\n")
    elif kind == "names":
        linear_onnx(path, card=card, names=("obs", "lidar", "action"))
    elif kind == "output":
        linear_onnx(path, card=card, names=("observation", "lidar", "act"))
    elif kind == "features":
        linear_onnx(path, num_obs=20, card=card)
    elif kind == "beams":
        linear_onnx(path, num_beams=32, card=card)
    elif kind == "width":
        linear_onnx(path, card=card, width=3)
    with pytest.raises(ConfigError) as e:
        resolve_policy(parse_policy_spec(f"onnx:{path}"))
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"policy = 'onnx:{path}'"), msg
    assert fragment in msg, msg


# ---------------------------------------------------------------------------------- module
@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """Write ``<name>.py`` in a fresh working directory (not on sys.path: the loader adds it)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    written = []

    def write(name: str, source: str) -> str:
        (tmp_path / f"{name}.py").write_text(textwrap.dedent(source))
        written.append(name)
        return name

    yield write
    for name in written:
        sys.modules.pop(name, None)


@pytest.mark.parametrize(
    ("source", "spec", "fragment"),
    [
        ("x = 1 / 0\n", "broken_mod:make", "module 'broken_mod' does not import (ZeroDivisionError"),
        ("", "absent_mod_xyz:make", "module 'absent_mod_xyz' does not import (ModuleNotFoundError"),
        ("def other(): pass\n", "nofn_mod:make", "module 'nofn_mod' has no 'make'"),
        ("make = 3\n", "attr_mod:make", "attr_mod.make is a int, not a function"),
        ("def make(): return 3\n", "int_mod:make", "attr_mod.make() returned a int"),
    ],
)  # fmt: skip
def test_bad_factories_are_one_line(user_module, source, spec, fragment):
    name = spec.partition(":")[0]
    if source:
        user_module(name, source)
    fragment = fragment.replace("attr_mod.make()", f"{name}.make()")
    with pytest.raises(ConfigError) as e:
        resolve_policy(parse_policy_spec(spec), env_config=SMALL_ENV)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"policy = {spec!r}") and fragment in msg, msg


CONTROLLER = """
import numpy as np
import torch
from tensordict.nn import TensorDictModule

SEEN = {}

def action(obs):  # half throttle, steer against the goal's lateral offset
    return torch.stack([torch.full_like(obs[:, 0], 0.5), (-0.4 * obs[:, 1]).clamp(-1, 1)], -1)

def td_to_td(env_config, device):
    SEEN.update(env_config=env_config, device=device)
    return lambda td: td.set("action", action(td["observation"]))

def td_to_action():
    return lambda td: action(td["observation"])

def arrays(env_config):
    return lambda observation, lidar: action(observation).numpy().astype(np.float64)

def module():
    return TensorDictModule(action, in_keys=["observation"], out_keys=["action"])
"""


def test_factories_in_every_convention_drive_the_same_episodes(user_module):
    user_module("drivers_conv", CONTROLLER)
    dock = base_env({"task": {"name": "dock"}})
    dock = dataclasses.replace(dock, max_steps=25)
    results = {}
    for fn in ("td_to_td", "td_to_action", "arrays", "module"):
        p = resolve_policy(parse_policy_spec(f"drivers_conv:{fn}"), "cpu", dock)
        assert p.env_config == dock and not p.fixed_env and p.difficulty is None
        results[fn], _, _ = evaluate_policy(p.actor, p.env_config, 0.0, episodes=6, seed=3)
    seen = sys.modules["drivers_conv"].SEEN
    assert seen == {"env_config": dock, "device": "cpu"}  # the factory got what it named
    ref = results["module"]  # a TorchRL module: passed through as it is
    assert ref["success"].any() or ref["collision"].any()  # the episodes did something
    for fn, res in results.items():
        assert res.keys() == ref.keys()
        for k in ref:  # outcomes, lengths, final errors, scenes, motion (NaN after the end)
            torch.testing.assert_close(
                res[k], ref[k], rtol=0, atol=0, equal_nan=True, msg=f"{fn} {k}"
            )


def test_as_policy_rejects_a_wrong_action_shape():
    td = TensorDict({"observation": torch.zeros(3, 26), "lidar": torch.zeros(3, 16)}, [3])
    with pytest.raises(ConfigError, match=r"action of shape \[3\], not \[3, 2\]"):
        as_policy(lambda td: torch.zeros(3))(td)
    assert as_policy(lambda o, li: np.ones((3, 2)))(td)["action"].dtype == torch.float32


# ---------------------------------------------------------------------------------- parity


@pytest.fixture(scope="module")
def shipped_export(tmp_path_factory):
    from truckrl.export import ExportConfig, export

    out = tmp_path_factory.mktemp("export") / "intersection.onnx"
    return export(ExportConfig(checkpoint="pretrained", out=str(out)))


@pytest.mark.parametrize(
    "scenes", [64, pytest.param(200, marks=pytest.mark.slow, id="200-done-when")]
)
def test_shipped_policy_and_its_onnx_export_have_identical_outcomes(shipped_export, scenes):
    """Same scenes (seed 12345, eval's default), same per-episode outcome and length (the
    default suite plays the first 64 of the 200 held-out scenes)."""
    torch_p = resolve_policy(parse_policy_spec("pretrained"))
    onnx_p = resolve_policy(parse_policy_spec(f"onnx:{shipped_export}"))
    assert onnx_p.env_config == torch_p.env_config and onnx_p.difficulty == torch_p.difficulty
    run = {}
    for name, p in (("torch", torch_p), ("onnx", onnx_p)):
        run[name], _, _ = evaluate_policy(p.actor, p.env_config, p.difficulty, scenes, seed=12345)
    a, b = run["torch"], run["onnx"]
    assert 0.5 < a["success"].float().mean() < 1.0  # a real mix of outcomes is compared
    for k in ("success", "collision", "jackknife", "truncated", "length"):
        flipped = int((a[k] != b[k]).sum())
        assert flipped == 0, f"{k}: {flipped} of {scenes} episodes differ"
    # two float32 runtimes: the final poses agree to the millimetre, not to the bit
    torch.testing.assert_close(a["pos_error"], b["pos_error"], atol=5e-3, rtol=0)
