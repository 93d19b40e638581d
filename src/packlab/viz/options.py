"""Defaults that ``packlab viz`` shows in its help, kept light to import (no plotting, no engine):
the command's parser reads them here, and the modules that draw and stream use them."""

from __future__ import annotations

#: Heightmap tiles an episode figure draws at most (``packlab.viz.render.episode_figure``).
EPISODE_MAX_STEPS = 40
#: Where a viewer started with ``rerun`` (or ``--spawn``) listens by default
#: (``packlab.viz.rerun_export``).
DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"

__all__ = ["DEFAULT_VIEWER_URL", "EPISODE_MAX_STEPS"]
