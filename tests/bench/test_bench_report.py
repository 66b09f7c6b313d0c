"""``truckrl.bench.report.write_json``: the record's provenance names the device measured."""

from __future__ import annotations

import json

from truckrl.bench.report import write_json


def test_the_provenance_device_is_the_payloads_or_its_commands(tmp_path):
    """bench train puts ``device`` in the payload, bench env in its ``args``: both reach the
    provenance line the docs print, where a GPU row must not read "device: cpu"."""
    top = json.loads(write_json("train", {"device": "cuda"}, tmp_path / "a.json").read_text())
    nested = write_json("env", {"args": {"device": "cuda:1"}}, tmp_path / "b.json")
    neither = write_json("lidar", {"rows": []}, tmp_path / "c.json")
    assert top["provenance"]["device"] == "cuda"
    assert json.loads(nested.read_text())["provenance"]["device"] == "cuda:1"
    assert json.loads(neither.read_text())["provenance"]["device"] == "cpu"
