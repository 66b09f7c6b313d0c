"""The vocabulary every layer shares: outcomes, flags, per-episode errors and their units.

One definition serves the task core, the env's specs, the training tracker, evaluation, the
viewer's HUD and TensorBoard. Angles are computed in radians and shown in degrees; the one
conversion is :func:`shown`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class Outcome:
    """How an episode can end.

    Attributes:
        name: metric name (``<name>_rate`` in logs and evaluation).
        flag: the env's boolean output key that marks it.
        label: banner text in the viewer.
        good: True for the outcome a policy should reach.
    """

    name: str
    flag: str
    label: str
    good: bool = False


OUTCOMES: tuple[Outcome, ...] = (
    Outcome("success", "success", "SUCCESS", good=True),
    Outcome("collision", "collision", "COLLISION"),
    Outcome("jackknife", "jackknife", "JACK-KNIFE"),
    Outcome("timeout", "truncated", "TIMEOUT"),
)

#: Boolean step outputs of every task (``truncated`` is a done key, not a flag).
FLAG_KEYS: tuple[str, ...] = ("success", "collision", "jackknife", "action_nonfinite")


@dataclass(frozen=True)
class Quantity:
    """A per-step scalar a task reports (its errors to the goal).

    Attributes:
        key: output key.
        unit: unit of the computed value ("m" or "rad").
        label: short human name.
    """

    key: str
    unit: str
    label: str

    @property
    def shown_unit(self) -> str:
        """Unit used in logs, tables and the HUD (degrees for angles)."""
        return "deg" if self.unit == "rad" else self.unit


@dataclass(frozen=True)
class CategoryDim:
    """One dimension along which evaluation splits a task's episodes (``Task.category_dims``).

    The value of each episode is ``info[key] * scale``, with ``info`` the scene metadata the task
    records at reset (``state["route"]``, plus ``trailer_length`` [m] for every task). Either
    ``edges`` (bins ``[lo, hi)``, the last one closed, in the scaled unit) or ``names`` (the
    value is an integer code ``i`` named ``names[i]``) is given.

    Attributes:
        label: dimension name in tables and TensorBoard, unit in brackets (``"bay width [m]"``).
        key: the metadata entry it reads.
        edges: bin edges, increasing (at least two), or None for a categorical dimension.
        names: names of the integer codes 0, 1, ..., or None for a binned dimension.
        scale: factor applied before binning (e.g. ``180 / pi`` for an angle shown in degrees).
    """

    label: str
    key: str
    edges: tuple[float, ...] | None = None
    names: tuple[str, ...] | None = None
    scale: float = 1.0

    def __post_init__(self) -> None:
        if (self.edges is None) == (self.names is None):
            raise ValueError(f"CategoryDim {self.label!r}: give exactly one of edges and names")
        if self.edges is not None and (
            len(self.edges) < 2
            or any(b <= a for a, b in zip(self.edges[:-1], self.edges[1:], strict=True))
        ):
            raise ValueError(f"CategoryDim {self.label!r}: edges must increase, at least two")


def shown(q: Quantity, value: Tensor) -> Tensor:
    """``value`` in ``q.shown_unit``: radians become degrees, everything else is unchanged."""
    return torch.rad2deg(value) if q.unit == "rad" else value


def shown_float(q: Quantity, value: float) -> float:
    """Scalar version of :func:`shown`."""
    return math.degrees(value) if q.unit == "rad" else value
