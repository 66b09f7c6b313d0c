"""The pygame window of ``truckrl play``: shows RGB frames and reports keys.

Deliberately thin: it turns pygame events into key names and the keyboard state into the set of
held drive keys (:class:`truckrl.viz.keyboard.KeyInput`); what keys mean lives in
:mod:`truckrl.viz.keyboard`, so it is tested without a display. Needs ``pygame`` (the ``viewer``
extra); tests run it with ``SDL_VIDEODRIVER=dummy`` and a scripted ``key_state``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable

import numpy as np

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
import pygame  # noqa: E402  (the variable above must be set before the import)

from truckrl.viz.keyboard import KeyInput  # noqa: E402

#: pygame key constant -> drive key name (the arrow keys are aliases of WASD).
_DRIVE = {
    pygame.K_w: "w",
    pygame.K_UP: "w",
    pygame.K_a: "a",
    pygame.K_LEFT: "a",
    pygame.K_s: "s",
    pygame.K_DOWN: "s",
    pygame.K_d: "d",
    pygame.K_RIGHT: "d",
}


def key_name(event) -> str:
    """Name of a KEYDOWN event's key: the typed character when printable ("+", "."), else
    pygame's key name ("escape", "space", "[+]")."""
    char = getattr(event, "unicode", "") or ""
    if len(char) == 1 and char.isprintable() and not char.isspace():
        return char.lower()
    return pygame.key.name(event.key)


def pygame_held() -> frozenset[str]:
    """Drive keys held now, read from pygame's keyboard state (so releases are always seen)."""
    state = pygame.key.get_pressed()
    return frozenset(name for key, name in _DRIVE.items() if state[key])


class Window:
    """A pygame window showing ``[H, W, 3]`` RGB frames at a fixed frame rate.

    Args:
        size: ``(width, height)`` [px], normally the frame size.
        title: window caption.
        key_state: returns the held drive keys; default :func:`pygame_held` (tests pass a script).
    """

    def __init__(
        self,
        size: tuple[int, int],
        title: str = "truckrl",
        key_state: Callable[[], Iterable[str]] | None = None,
    ) -> None:
        pygame.display.init()
        #: SDL video driver in use; "offscreen" or "dummy" means nothing is visible
        self.driver: str = pygame.display.get_driver()
        self.screen = pygame.display.set_mode(size)
        pygame.display.set_caption(title)
        self.clock = pygame.time.Clock()
        self._key_state = key_state or pygame_held

    def poll(self) -> KeyInput:
        """Keys pressed since the last call, keys held now, and whether the window was closed."""
        pressed: list[str] = []
        quit_ = False
        for event in pygame.event.get():
            if event.type == pygame.QUIT:
                quit_ = True
            elif event.type == pygame.KEYDOWN:
                pressed.append(key_name(event))
        return KeyInput(frozenset(self._key_state()), tuple(pressed), quit_)

    def show(self, frame: np.ndarray) -> None:
        """Draw an RGB frame ``[H, W, 3]`` uint8 at the top-left corner and flip the display."""
        surface = pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
        self.screen.blit(surface, (0, 0))
        pygame.display.flip()

    def tick(self, fps: float) -> None:
        """Sleep so that successive calls run at ``fps`` frames/s at most."""
        self.clock.tick(fps)

    def close(self) -> None:
        pygame.display.quit()
