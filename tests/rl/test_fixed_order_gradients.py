"""A compiled backward at two threads gives the same gradient every time once training has set up
(:func:`truckrl.rl.trainer.fixed_order_gradients`): the reason a seed repeats its run at 2 threads."""

from __future__ import annotations

import subprocess
import sys

from tests.conftest import ROOT

#: Eight backward passes of the compiled LiDAR encoder (its ring matrix is gathered from the
#: kernel weights, so its weight gradient is a scatter-add) on one batch, at two threads; prints
#: how many distinct gradients they gave.
SCRIPT = """
import sys, torch
torch.set_num_threads(2)
from truckrl.rl.config import ModelConfig
from truckrl.rl.network import LidarEncoder
from truckrl.rl.trainer import fixed_order_gradients
if sys.argv[1] == "fixed":
    fixed_order_gradients("cpu")
torch.manual_seed(0)
enc = LidarEncoder(32, ModelConfig())
x = torch.rand(4096, 32)
loss = torch.compile(lambda x: enc(x).square().sum())
grads = set()
for _ in range(8):
    enc.zero_grad()
    loss(x).backward()
    grads.add(torch.cat([p.grad.flatten() for p in enc.parameters()]).numpy().tobytes())
print(len(grads))
"""


def distinct_gradients(mode: str) -> int:
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, mode], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    return int(proc.stdout.split()[-1])


def test_a_compiled_backward_at_two_threads_repeats_bit_for_bit():
    assert distinct_gradients("fixed") == 1
