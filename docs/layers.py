"""Draw docs/layers.png: the package's layers, their modules and the imports between them.

Run from the repository root: ``python docs/layers.py``. The layers and their order come from
``tests/test_layers.py`` (the map the test enforces); the modules and the import counts are read
from the source, so the picture is redrawn from the code, never by hand.
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.test_layers import ALLOWED, FILES, layer_of, module_name, truckrl_imports  # noqa: E402

#: Drawing order, top to bottom (the entry points on top, as in docs/architecture.md).
ORDER = (
    "main",
    "entry",
    "cli",
    "schemas",
    "viewer",
    "api",
    "rl",
    "planning",
    "gym",
    "evaluation",
    "env",
    "viz",
    "task",
    "sim",
    "config",
)
W, ROW, PAD, BOX_W = 1400, 62, 14, 760
FONT = cv2.FONT_HERSHEY_SIMPLEX


def measure() -> tuple[dict[str, list[str]], Counter]:
    """Modules per layer and the number of imports from each layer into each lower one."""
    modules: dict[str, list[str]] = {layer: [] for layer in ORDER}
    edges: Counter = Counter()
    for path in FILES:
        name = module_name(path)
        layer = layer_of(name)
        modules[layer].append(name)
        for target in truckrl_imports(path):
            other = layer_of(target)
            if other != layer:
                edges[layer, other] += 1
    return modules, edges


def _short(module: str) -> str:
    """``truckrl.rl.ppo`` -> ``rl``; a task folder's module -> ``tasks/*/<file>``."""
    parts = module.split(".")[1:] or ["truckrl"]
    if parts[0] == "tasks" and len(parts) > 2:
        return f"tasks/*/{parts[2]}"
    return parts[0] if parts[0] != "config" else ".".join(parts[:2])


def draw(modules: dict[str, list[str]], edges: Counter) -> np.ndarray:
    h = PAD * 2 + ROW * len(ORDER) + 40
    img = np.full((h, W, 3), 255, np.uint8)
    y_of = {layer: PAD + 40 + i * ROW for i, layer in enumerate(ORDER)}
    cv2.putText(img, "truckrl layers (imports go down)", (PAD, 30), FONT, 0.8, (0, 0, 0), 2)
    for layer in ORDER:
        y = y_of[layer]
        cv2.rectangle(img, (PAD, y), (PAD + BOX_W, y + ROW - 12), (235, 225, 210), -1)
        cv2.rectangle(img, (PAD, y), (PAD + BOX_W, y + ROW - 12), (120, 100, 80), 1)
        names = sorted({_short(m) for m in modules[layer]})
        label = f"{layer} ({len(modules[layer])} modules)"
        cv2.putText(img, label, (PAD + 8, y + 20), FONT, 0.55, (0, 0, 0), 1)
        text = ", ".join(names)
        cv2.putText(img, text[:95], (PAD + 8, y + 40), FONT, 0.42, (60, 60, 60), 1)
    # arrows on the right: one column per importing layer, to each layer it imports
    x0 = PAD + BOX_W + 30
    step = (W - x0 - PAD) // max(1, len(ORDER))
    for i, src in enumerate(ORDER):
        x = x0 + i * step
        for dst in ORDER:
            n = edges.get((src, dst), 0)
            if not n:
                continue
            y1, y2 = y_of[src] + 20, y_of[dst] + 30
            good = dst in ALLOWED[src]
            color = (60, 140, 60) if good else (0, 0, 220)
            cv2.arrowedLine(img, (x, y1), (x, y2), color, 1 + (n > 10), tipLength=8 / abs(y2 - y1))
            cv2.putText(img, str(n), (x + 3, y2 - 2), FONT, 0.35, color, 1)
        cv2.putText(img, src[:4], (x - 6, PAD + 30), FONT, 0.35, (0, 0, 0), 1)
    return img


def main() -> int:
    modules, edges = measure()
    out = ROOT / "docs" / "layers.png"
    cv2.imwrite(str(out), draw(modules, edges))
    upward = [(s, d, n) for (s, d), n in edges.items() if d not in ALLOWED[s]]
    print(f"wrote {out}: {sum(map(len, modules.values()))} modules, {len(upward)} upward edges")
    return 1 if upward else 0


if __name__ == "__main__":
    sys.exit(main())
