"""Keyboard driving without a window: held keys -> action, pressed keys -> viewer commands.

Pure Python (no pygame): the window layer only reports key names, so everything here is testable
and the same mapping drives scripted key files (``truckrl play actions=keys.txt``).

Held keys (``w``, ``a``, ``s``, ``d``; the window also maps the arrow keys onto them) become the
action ``[longitudinal, lateral]`` in ``[-1, 1]``, in the units of the configured control mode
(:mod:`truckrl.sim.control`): W = +longitudinal, S = -longitudinal (brake), A = steer left
(+lateral), D = steer right. Opposite keys held together cancel. Per mode:

==============  =========================================  ====================================
mode            key held                                   nothing held
==============  =========================================  ====================================
accel, jerk     W/S: +1 / -1 (full accel or jerk)          0 (accel mode: keep the speed;
(long.)                                                    jerk mode: keep the acceleration)
speed (long.)   W/S: set-point moves up/down by            hold the current speed (cruise)
                ``setpoint_rate * dt`` per step
rate, accel     A/D: +1 / -1 (full steer rate or accel)    0 (rate mode: keep the wheel angle;
(lateral)                                                  accel mode: keep the steer rate)
angle (lat.)    A/D: set-point moves left/right by         the wheel returns toward centre by
                ``setpoint_rate * dt`` per step            ``center_rate * dt`` per step
==============  =========================================  ====================================

Set-point modes start from the commanded quantity's current value on the action scale (so a
speed set-point never runs away from the real speed).

Reversing: in a task that reverses (``Task.reverse``) the speed goes down to the truck's
``-max_reverse_speed`` instead of stopping at 0, so the same keys drive backwards: holding S
brakes to a standstill and, held on, engages reverse (the speed goes negative, down to
``-max_reverse_speed``); W at a negative speed brakes to 0 and then drives forward. Nothing else
changes: in a forward-only task S stops the truck at 0. The panel shows the gear
(:func:`gear`): D forward, R reverse, N at rest.

Viewer commands (:data:`COMMAND_KEYS`): R restart the scene, N new scene, P/Space pause,
``.`` one step while paused, ``+``/``-`` difficulty up/down, M manual/policy, Q/Esc quit.

Scripted key file (:func:`parse_key_script`), one entry per line, ``#`` starts a comment::

    W 20        # hold W for 20 frames
    WD 5        # hold W and D for 5 frames
    - 3         # nothing held for 3 frames (also "_")
    !r          # press R before the next frame (a command key; several: "!n !+")
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass

from truckrl.config.fields import ConfigError, check_range, from_mapping, param, validate
from truckrl.sim.control import ControlConfig

DRIVE_KEYS: tuple[str, ...] = ("w", "a", "s", "d")


class Command(enum.Enum):
    """Viewer commands bound to single key presses."""

    RESTART = "restart the scene"
    NEW_SCENE = "new random scene"
    PAUSE = "pause / resume"
    STEP = "one step while paused"
    HARDER = "difficulty up"
    EASIER = "difficulty down"
    TOGGLE_MODE = "manual / policy"
    QUIT = "quit"


#: Key name (pygame's ``key.name`` or the typed character) -> command.
COMMAND_KEYS: dict[str, Command] = {
    "r": Command.RESTART,
    "n": Command.NEW_SCENE,
    "p": Command.PAUSE,
    "space": Command.PAUSE,
    " ": Command.PAUSE,
    ".": Command.STEP,
    "[.]": Command.STEP,
    "+": Command.HARDER,
    "=": Command.HARDER,
    "[+]": Command.HARDER,
    "-": Command.EASIER,
    "[-]": Command.EASIER,
    "m": Command.TOGGLE_MODE,
    "q": Command.QUIT,
    "escape": Command.QUIT,
}

#: On-screen key help, two columns.
KEY_HELP: tuple[tuple[str, str], ...] = (
    ("W / S", "faster / slower (brake)"),
    ("A / D", "steer left / right"),
    ("R", "restart this scene"),
    ("N", "new random scene"),
    ("P, Space", "pause / resume"),
    (".", "one step (paused)"),
    ("+ / -", "difficulty +/- step"),
    ("M", "manual / policy"),
    ("Q, Esc", "quit"),
)


#: The W / S help line of a task that reverses.
REVERSE_HELP: tuple[str, str] = ("W / S", "forward / brake, reverse")


def key_help(with_policy: bool, reverse: bool = False) -> tuple[tuple[str, str], ...]:
    """:data:`KEY_HELP` without the M line when there is no policy to switch to; with
    ``reverse`` (a task that reverses) the W / S line says that S reverses at rest."""
    rows = (REVERSE_HELP if reverse and row[0] == "W / S" else row for row in KEY_HELP)
    return tuple(row for row in rows if with_policy or row[0] != "M")


#: [m/s] Below this |speed| the truck counts as at rest (gear N).
REST_SPEED = 0.01


def gear(speed: float) -> str:
    """The gear shown for a speed [m/s]: ``"D"`` forward, ``"R"`` reverse, ``"N"`` at rest
    (``|speed| < REST_SPEED``)."""
    if speed >= REST_SPEED:
        return "D"
    return "R" if speed <= -REST_SPEED else "N"


def command_for(key: str) -> Command | None:
    """The command bound to key name ``key`` (case-insensitive), or ``None``."""
    return COMMAND_KEYS.get(key.lower())


@dataclass(frozen=True)
class KeyboardConfig:
    """Set-point speeds of the keyboard mapping (``keyboard.*`` of the viewer).

    A rate of 1.0 action units / s moves a set-point from one end of the range to the middle in
    1 s.
    """

    setpoint_rate: float = param(
        1.0,
        lo=0.0,
        lo_open=True,
        hi=1e3,
        unit="action units/s",
        doc="how fast W/S (speed mode) or A/D (angle mode) move the set-point",
    )
    center_rate: float = param(
        2.0,
        lo=0.0,
        hi=1e3,
        unit="action units/s",
        doc="angle mode: how fast the wheel returns toward centre while A and D are released",
    )

    def __post_init__(self) -> None:
        validate(self, "keyboard")


def _push(held: frozenset[str], plus: str, minus: str) -> float:
    return float(plus in held) - float(minus in held)


class KeyMapper:
    """Maps the set of held keys to the action of one step (see the module table).

    Args:
        control: the control modes the action commands.
        cfg: set-point speeds.
        dt: env step [s] (set-points move by ``rate * dt`` per step).
    """

    def __init__(self, control: ControlConfig, cfg: KeyboardConfig, dt: float) -> None:
        self.control = from_mapping(ControlConfig, control, "control")
        self.cfg = from_mapping(KeyboardConfig, cfg, "keyboard")
        self.dt = check_range("dt", dt, 0.0, 1.0, lo_open=True)

    def action(self, held: Iterable[str], current: tuple[float, float]) -> tuple[float, float]:
        """Action ``(longitudinal, lateral)`` in ``[-1, 1]``.

        Args:
            held: names of the keys held now (``"w"``, ``"a"``, ``"s"``, ``"d"``; others ignored).
            current: the commanded quantities' present values on the action scale (only read in
                the speed and angle modes), e.g. ``steer / max_steer``.
        """
        keys = frozenset(k.lower() for k in held)
        lon = _push(keys, "w", "s")
        lat = _push(keys, "a", "d")
        step = self.cfg.setpoint_rate * self.dt
        if self.control.longitudinal == "speed":
            lon = _clip(current[0] + lon * step)
        if self.control.lateral == "angle":
            if lat:
                lat = _clip(current[1] + lat * step)
            else:
                back = self.cfg.center_rate * self.dt
                lat = _clip(current[1] - max(-back, min(back, current[1])))
        return lon, lat


def _clip(u: float) -> float:
    return max(-1.0, min(1.0, u))


@dataclass(frozen=True)
class KeyInput:
    """What one frame of input holds: keys down now, keys pressed since the last frame, quit."""

    held: frozenset[str] = frozenset()
    pressed: tuple[str, ...] = ()
    quit: bool = False


def parse_key_script(text: str, source: str = "key script") -> list[KeyInput]:
    """Parse the scripted key format of the module docstring into one :class:`KeyInput` per frame.

    Presses (``!key``) are attached to the next frame; presses after the last hold line get a
    frame of their own with nothing held.

    Raises:
        ConfigError: an unknown key or a bad frame count, naming the line.
    """
    frames: list[KeyInput] = []
    pending: list[str] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        tokens = raw.split("#", 1)[0].split()
        if not tokens:
            continue
        where = f"{source} line {lineno}"
        if tokens[0].startswith("!"):
            for tok in tokens:
                name = tok[1:].lower()
                if not tok.startswith("!") or command_for(name) is None:
                    raise ConfigError(
                        f"{where}: {tok!r} is not a command key "
                        f"(one of {', '.join('!' + k for k in sorted(COMMAND_KEYS) if k != ' ')})"
                    )
                pending.append(name)
            continue
        if len(tokens) > 2:
            raise ConfigError(f"{where}: expected '<keys> [frames]', got {raw.strip()!r}")
        keys = tokens[0].lower()
        held = frozenset() if keys in ("-", "_") else frozenset(keys)
        if not held <= set(DRIVE_KEYS):
            raise ConfigError(f"{where}: keys {tokens[0]!r} must be letters of WASD, or - for none")
        try:
            count = int(tokens[1]) if len(tokens) == 2 else 1
        except ValueError:
            raise ConfigError(f"{where}: frame count {tokens[1]!r} is not an integer") from None
        if not 1 <= count <= 1_000_000:
            raise ConfigError(f"{where}: frame count {count} must be in [1, 1000000]")
        frames.append(KeyInput(held, tuple(pending)))
        frames += [KeyInput(held)] * (count - 1)
        pending = []
    if pending:
        frames.append(KeyInput(frozenset(), tuple(pending)))
    return frames


class ScriptedKeys:
    """An input that replays a parsed key script, one :class:`KeyInput` per frame.

    ``poll()`` returns ``None`` once the script is used up.
    """

    def __init__(self, frames: list[KeyInput]) -> None:
        self._frames = list(frames)
        self._next = 0

    def poll(self) -> KeyInput | None:
        if self._next >= len(self._frames):
            return None
        self._next += 1
        return self._frames[self._next - 1]


class NoKeys:
    """An input with nothing held and nothing pressed, forever (headless policy playback)."""

    def poll(self) -> KeyInput:
        return KeyInput()
