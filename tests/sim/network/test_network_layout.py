"""Networks from a list of blocks (YAML): built as written, and one-line errors for bad input."""

from __future__ import annotations

import math

import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim.network import NetworkConfig
from truckrl.sim.network.layout import load_layout

LAYOUT = """
road_width: 9.0
heading_deg: 90
blocks:
  - {type: straight, length: 40}
  - {type: curve, radius: 30, angle_deg: -60}
  - {type: crossing, angle_deg: 90, arm: 25, entry: 0, exit: 3}
  - {type: roundabout, radius: 15, arms: 3, arm: 15, exit: 2}
  - {type: median, length: 60, width: 2}
"""


def test_a_layout_is_built_as_written(tmp_path):
    path = tmp_path / "yard.yaml"
    path.write_text(LAYOUT)
    net = load_layout(path)
    assert net.num_blocks.tolist() == [5]
    assert net.block_type.tolist() == [[0, 1, 2, 4, 5]]
    # block 0 heads north from the origin: its exit is 40 m up; the right curve of 60 degrees
    # ends at 30 (1 - cos 60) to the right (+x) and 30 sin 60 further north
    torch.testing.assert_close(net.sockets[0, 0, 1], torch.tensor([0.0, 40.0, math.pi / 2]))
    end = net.sockets[0, 1, 1]
    torch.testing.assert_close(
        end[:2], torch.tensor([30 * (1 - math.cos(math.pi / 3)), 40 + 30 * math.sin(math.pi / 3)])
    )
    assert net.exit.tolist() == [[1, 1, 3, 2, -1]]


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            ("radius: 30", "radius: 5"),
            "blocks[1].radius = 5 is outside the allowed range [20.0, 60.0]",
        ),
        (
            ("angle_deg: -60", "angle_deg: -10"),
            "blocks[1].angle_deg = -10 is outside the allowed range",
        ),
        (("exit: 3", "exit: 0"), "blocks[2].exit = 0 must differ from blocks[2].entry = 0"),
        (("exit: 2", "exit: 3"), "blocks[3].exit = 3 must be a socket number in [0, 2]"),
        (("type: median", "type: moat"), "blocks[4].type = 'moat' is not one of"),
        (
            ("road_width: 9.0", "road_width: 30"),
            "road_width = 30 is outside the allowed range [8.0, 10.0]",
        ),
        (("length: 40", "lenght: 40"), "unknown field(s) ['lenght'] for blocks[0] (straight)"),
        (("arms: 3", "arms: 3.5"), "blocks[3].arms = 3.5 must be a whole number in [3, 4]"),
    ],
)
def test_bad_fields_are_one_line_errors_naming_field_and_range(tmp_path, edit, message):
    path = tmp_path / "bad.yaml"
    path.write_text(LAYOUT.replace(*edit))
    with pytest.raises(ConfigError) as e:
        load_layout(path)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_a_layout_that_loops_onto_itself_is_refused(tmp_path):
    """Four left quarter circles of one radius end where the first starts: the fourth closes
    the loop onto the first (closer than network.clearance); three are fine."""
    cfg = NetworkConfig(num_blocks=(1, 6))
    path = tmp_path / "loop.yaml"
    curve = "  - {type: curve, radius: 20, angle_deg: 90}\n"
    path.write_text("road_width: 9\nblocks:\n" + curve * 3)
    assert load_layout(path, cfg).num_blocks.tolist() == [3]
    path.write_text("road_width: 9\nblocks:\n" + curve * 4)
    with pytest.raises(ConfigError, match=r"blocks\[3\] \(curve\) overlaps an earlier block"):
        load_layout(path, cfg)
