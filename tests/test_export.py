"""``python -m truckrl.export``: the exported model computes the PyTorch actor's mean action."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

import truckrl.export as export_module
from tests.conftest import run_cli
from tests.reliability.harness import assert_one_line_error, run_main
from truckrl.config.fields import ConfigError, build
from truckrl.env import TruckEnv
from truckrl.export import (
    CARD_KEY,
    DeterministicActor,
    ExportConfig,
    ExportVerificationError,
    export,
    observation_table,
    verify,
)
from truckrl.rl.policy import load_policy
from truckrl.tasks import EnvConfig


def random_inputs(n: int, num_obs: int, num_beams: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(n, num_obs, generator=g) * 2.0
    lidar = torch.rand(n, num_beams, generator=g)
    return obs, lidar


def actor_mean(ac, obs, lidar) -> torch.Tensor:
    """The PyTorch actor's action under deterministic exploration (what evaluation plays)."""
    from tensordict import TensorDict

    td = TensorDict({"observation": obs, "lidar": lidar}, batch_size=[len(obs)])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        return ac.actor(td)["action"]


def test_torchscript_matches_the_actor(tiny_checkpoint, tmp_path):
    run, ac, tc = tiny_checkpoint
    out = export(
        ExportConfig(checkpoint=str(run), format="torchscript", out=str(tmp_path / "p.pt"))
    )
    extra = {f"{CARD_KEY}.json": ""}
    model = torch.jit.load(str(out), _extra_files=extra)
    for n in (1, 7):  # the batch size is free
        obs, lidar = random_inputs(n, 26, tc.env.lidar.num_beams, seed=n)
        got = model(obs, lidar)
        torch.testing.assert_close(got, actor_mean(ac, obs, lidar), atol=1e-5, rtol=0)
    card = json.loads(extra[f"{CARD_KEY}.json"])
    assert card["inputs"]["observation"]["shape"] == ["batch", 26]
    assert card["inputs"]["lidar"]["shape"] == ["batch", tc.env.lidar.num_beams]
    assert "not applied" in card["output"]["action"]["clamp"]


def test_onnx_matches_the_actor(tiny_checkpoint, tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxscript")
    ort = pytest.importorskip("onnxruntime")
    run, ac, tc = tiny_checkpoint
    out = export(ExportConfig(checkpoint=str(run), format="onnx", out=str(tmp_path / "p.onnx")))
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["observation", "lidar"]
    for n in (1, 5, 64):
        obs, lidar = random_inputs(n, 26, tc.env.lidar.num_beams, seed=n)
        (got,) = session.run(["action"], {"observation": obs.numpy(), "lidar": lidar.numpy()})
        np.testing.assert_allclose(got, actor_mean(ac, obs, lidar).numpy(), atol=1e-5, rtol=0)
    card = json.loads(session.get_modelmeta().custom_metadata_map[CARD_KEY])
    table = card["inputs"]["observation"]["table"]
    assert [row["index"] for row in table] == list(range(26))
    assert (
        table[0]["meaning"].startswith("goal rear axle x") and table[0]["normalisation"] == "/ 50 m"
    )
    assert table[14]["meaning"] == "wheelbase"
    # the last two: limits of the checkpoint's control mode (accel / steering rate by default)
    assert table[24]["meaning"].startswith("max accel") and table[25]["meaning"].startswith(
        "max steer rate"
    )
    assert len(card["inputs"]["lidar"]["beam_angles_deg"]) == tc.env.lidar.num_beams
    assert build(EnvConfig, card["env_config"], "env") == tc.env  # eval policy=onnx: reads it
    # the verification that export ran tells this file from another policy's
    loaded = load_policy(run)
    other = perturbed(DeterministicActor(loaded.actor))
    with pytest.raises(ExportVerificationError, match="onnxruntime's actions differ"):
        verify(out, "onnx", other, loaded)


def perturbed(model: DeterministicActor, by: float = 1e-3) -> DeterministicActor:
    """A copy of ``model`` with every weight moved by ``by``: a wrong file's policy."""
    import copy

    bad = copy.deepcopy(model)
    with torch.no_grad():
        for p in bad.parameters():
            p.add_(by)
    return bad


def write_perturbed_torchscript(model, inputs, card, out):
    """What a faulty writer would leave: a TorchScript file of the wrong weights."""
    torch.jit.save(torch.jit.trace(perturbed(model), inputs), str(out))


def test_a_file_that_fails_verification_is_removed_and_the_old_one_kept(
    tiny_checkpoint, tmp_path, monkeypatch
):
    run, _, _ = tiny_checkpoint
    out = tmp_path / "p.pt"
    out.write_bytes(b"the previous export")
    monkeypatch.setattr(export_module, "export_torchscript", write_perturbed_torchscript)
    with pytest.raises(ExportVerificationError, match=r"torch.jit.load's actions differ .* on "
                       r"704 real observations \(tolerance 0.0001\)"):  # fmt: skip
        export(ExportConfig(checkpoint=str(run), format="torchscript", out=str(out)))
    assert out.read_bytes() == b"the previous export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.pt"]  # no temporary file left


def test_a_model_the_onnx_checker_rejects_is_not_written(tiny_checkpoint, tmp_path, monkeypatch):
    from onnx import TensorProto, helper

    run, _, _ = tiny_checkpoint

    def invalid(model, inputs, card, out, opset=None):  # a node reads a tensor nobody makes
        info = helper.make_tensor_value_info
        graph = helper.make_graph(
            [helper.make_node("Relu", ["nowhere"], ["action"])],
            "bad",
            [info("observation", TensorProto.FLOAT, ["b", 26])],
            [info("action", TensorProto.FLOAT, ["b", 2])],
        )
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
        out.write_bytes(model.SerializeToString())

    pytest.importorskip("onnx")
    monkeypatch.setattr(export_module, "export_onnx", invalid)
    with pytest.raises(ExportVerificationError, match="the ONNX checker rejects it: .*nowhere"):
        export(ExportConfig(checkpoint=str(run), out=str(tmp_path / "p.onnx")))
    assert list(tmp_path.iterdir()) == []


def test_failed_verification_is_one_line_and_exit_code_1(
    tiny_checkpoint, tmp_path, monkeypatch, capsys
):
    run, _, _ = tiny_checkpoint
    monkeypatch.setattr(export_module, "export_torchscript", write_perturbed_torchscript)
    out = tmp_path / "p.pt"
    r = run_main(capsys, "export", f"checkpoint={run}", "format=torchscript", f"out={out}",
                 f"hydra.run.dir={tmp_path}")  # fmt: skip
    assert r.code == 1 and "Traceback" not in r.err, r.err
    lines = r.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: export not written, verification")
    assert "export:" not in r.out and not out.exists()


def test_observation_table_matches_the_env():
    env = TruckEnv(num_envs=1)
    assert len(observation_table(env.config)) == env.observation_spec["observation"].shape[-1]


def test_config_errors():
    with pytest.raises(ConfigError, match="checkpoint is required"):
        ExportConfig()
    with pytest.raises(ConfigError, match="format"):
        ExportConfig(checkpoint="x", format="tflite")


@pytest.mark.e2e
def test_cli_writes_next_to_the_run_and_bad_checkpoint_is_exit_2(tiny_checkpoint, tmp_path, capsys):
    run, ac, tc = tiny_checkpoint
    proc = run_cli("export", f"checkpoint={run}", "format=torchscript", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "verified: torch.jit.load: max |action - torch policy's| = " in proc.stdout
    model = torch.jit.load(str(run / "export" / "policy.pt"))  # this run's actor, beside it
    obs, lidar = random_inputs(5, 26, tc.env.lidar.num_beams, seed=3)
    torch.testing.assert_close(model(obs, lidar), actor_mean(ac, obs, lidar), atol=1e-5, rtol=0)
    r = run_main(capsys, "export", f"checkpoint={tmp_path / 'none'}", f"hydra.run.dir={tmp_path}")
    assert_one_line_error(r, "not found")
