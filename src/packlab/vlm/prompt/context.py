"""Observation -> chat messages for the inference policies (no torch).

Both the local ``vlm`` policy and the ``endpoint`` policy render the context X_t with
:func:`packlab.vlm.prompt.render.render_messages` from
:func:`packlab.vlm.prompt.render.turns_from_observation`, with heightmap images drawn by
:func:`packlab.sim.raster.heightmap_to_image` at the size the data engine writes (224 px by
default). A past heightmap never changes, so each distinct heightmap is
drawn once per episode (a memo keyed by the array's bytes, cleared on :meth:`reset`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from packlab.core.types import Container, Observation
from packlab.sim.raster import heightmap_to_image
from packlab.vlm.prompt.render import (
    BLANK_IMAGE,
    PromptOptions,
    render_messages,
    turns_from_observation,
)

#: Side of the heightmap images, as the data engine writes them (DatagenConfig.image_size).
DEFAULT_IMAGE_SIZE = 224


class ContextRenderer:
    """Renders an observation's context; images are PIL RGB images of ``image_size`` px.

    ``blank`` is what image entries hold under ``image="blank"``: the :data:`BLANK_IMAGE` marker
    (the local processor resolves it to an all-zero image, as in training) or a real image.
    """

    def __init__(
        self,
        options: PromptOptions | None = None,
        image_size: int = DEFAULT_IMAGE_SIZE,
        blank: Any = BLANK_IMAGE,
    ) -> None:
        if image_size < 16:
            raise ValueError(f"image_size = {image_size}: must be >= 16 px")
        self.options = options if options is not None else PromptOptions()
        self.image_size = image_size
        self.blank = blank
        self._memo: dict[tuple, Any] = {}

    def reset(self) -> None:
        self._memo.clear()

    def image(self, heightmap: np.ndarray, container: Container) -> Any:
        """The (memoised) image of one heightmap."""
        hm = np.ascontiguousarray(heightmap)
        key = (container, hm.shape, str(hm.dtype), hm.tobytes())
        im = self._memo.get(key)
        if im is None:
            im = heightmap_to_image(hm, container, self.image_size)
            self._memo[key] = im
        return im

    def messages(self, obs: Observation) -> list[dict[str, Any]]:
        """The context X_t (system, past turns, current turn) for ``obs``."""
        if self.options.image == "heightmap":

            def render(hm: np.ndarray) -> Any:
                return self.image(hm, obs.container)
        else:  # blank / none: the picture is never shown, so never drawn

            def render(hm: np.ndarray) -> Any:
                return None

        past, current = turns_from_observation(obs, render)
        return render_messages(obs.container, past, current, self.options, blank=self.blank)
