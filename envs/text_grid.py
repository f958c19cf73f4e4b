"""Rendering shared by the grid worlds: the book's text grid, printed or as an RGB picture."""

from __future__ import annotations

import numpy as np


class TextGridRendering:
    """Mixin: ``render()`` for envs that draw themselves as the book's text grid.

    The env provides ``render_mode``, ``grid_text() -> str`` and ``_rgb() -> np.ndarray`` (H, W, 3) uint8.
    ``"ansi"`` returns the text, ``"human"`` prints it, ``"rgb_array"`` returns the picture.
    """

    render_mode: str | None

    def grid_text(self) -> str:
        raise NotImplementedError

    def _rgb(self) -> np.ndarray:
        raise NotImplementedError

    def render(self) -> str | np.ndarray | None:
        if self.render_mode == "ansi":
            return self.grid_text()
        if self.render_mode == "human":
            print(self.grid_text() + "\n")
            return None
        if self.render_mode == "rgb_array":
            return self._rgb()
        return None
