"""The sim package stands alone: importable without TorchRL, and its docstring example runs."""

import subprocess
import sys


def test_sim_imports_without_torchrl_and_example_runs():
    code = (
        "import sys, builtins\n"
        "real = builtins.__import__\n"
        "def guard(name, *a, **k):\n"
        "    if name.split('.')[0] in ('torchrl', 'tensordict'):\n"
        "        raise ImportError('sim must not import ' + name)\n"
        "    return real(name, *a, **k)\n"
        "builtins.__import__ = guard\n"
        "import truckrl.sim as sim\n"
        "doc = sim.__doc__.split('::')[1]\n"
        "src = '\\n'.join(line[4:] for line in doc.splitlines())\n"
        "ns = {}\n"
        "exec(src, ns)\n"
        "assert ns['ranges'].shape == (8, 16)\n"
        "assert (ns['ranges'] <= 50.0).all() and (ns['ranges'] > 0).all()\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
