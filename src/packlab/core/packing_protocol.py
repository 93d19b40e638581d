"""The episode's protocol: packlab's buffered one, or the field's online one.

* ``buffer`` (packlab's, DESIGN.md section 4): the first ``buffer_size`` unprocessed boxes of
  the case are shown in a seeded shuffled order, the policy may place any of them, and every box
  is processed.
* ``online`` (the field's: Zhao et al., AAAI 2021, and their follow-ups): the next ``lookahead``
  boxes are shown in arrival order and the policy must place the first one (BPP-1 at k = 1,
  BPP-k above); an action naming another shown box is invalid (``not_first``). The episode ends
  at the first box that fits nowhere (:func:`packlab.core.feasibility.fits_somewhere`), and space
  utilization counts the volume packed up to it. The case's ``buffer_size`` is not used.
* ``offline`` (the reference the other two are measured against): every unprocessed box is
  shown (in the buffer protocol's seeded shuffled order) and any may be placed; every box is
  processed. The same cases with
  the whole sequence in view measure what the buffer or the online protocol costs a policy
  (the online gap), including on cases without a perfect packing.

One typed value (:class:`PackingProtocol`) carries the choice from the command line to the
episode; its :meth:`~PackingProtocol.identity` is what a run directory's ``config.json`` records
and :func:`saved_protocol` reads any version's entry back (an absent key is ``buffer``: every run
made before the choice existed).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import cast

from packlab.core.choices import DEFAULT_PROTOCOL, EpisodeProtocol, require_choice
from packlab.core.errors import ConfigError

#: The online protocol's lookahead unless told (BPP-1, the field's strict setting).
DEFAULT_LOOKAHEAD = 1
#: The largest lookahead accepted: the field reports k up to 10; larger is a typo.
MAX_LOOKAHEAD = 100


@dataclass(frozen=True, slots=True)
class PackingProtocol:
    """Which protocol an episode follows and, online, how many boxes it shows."""

    name: EpisodeProtocol = DEFAULT_PROTOCOL
    #: Online: boxes shown, in arrival order (the first must be placed). Not used by ``buffer``
    #: (its window is the case's ``buffer_size``), where it must stay the default.
    lookahead: int = DEFAULT_LOOKAHEAD

    def __post_init__(self) -> None:
        require_choice(self.name, EpisodeProtocol, "protocol")
        k = self.lookahead
        if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= MAX_LOOKAHEAD:
            raise ConfigError(f"lookahead = {k!r}: must be a whole number in 1..{MAX_LOOKAHEAD}")
        if self.name != "online" and k != DEFAULT_LOOKAHEAD:
            raise ConfigError(
                f"lookahead = {k}: only used with --protocol online (the buffer protocol shows "
                "the case's buffer_size boxes, the offline one every box)"
            )

    @property
    def online(self) -> bool:
        return self.name == "online"

    def shown_count(self, buffer_size: int, unprocessed: int) -> int:
        """How many unprocessed boxes are shown at once (fewer near the end of a case)."""
        if self.name == "offline":
            return unprocessed
        return self.lookahead if self.online else buffer_size

    @property
    def label(self) -> str:
        """How a table or an error names it: ``buffer``, ``online (BPP-1)``, ``online (BPP-3)``."""
        if self.name == "offline":
            return "offline (every box shown)"
        return f"online (BPP-{self.lookahead})" if self.online else "buffer"

    def identity(self) -> dict[str, str | int]:
        """config.json's entries: ``protocol``, and ``lookahead`` for the online protocol."""
        if not self.online:
            return {"protocol": self.name}
        return {"protocol": self.name, "lookahead": self.lookahead}


#: packlab's own protocol, the default (and what a run that records no protocol used).
BUFFER = PackingProtocol()


def saved_protocol(config: Mapping[str, object] | None) -> PackingProtocol:
    """The protocol a run's config.json (or summary.json) records; an absent ``protocol`` key
    reads as ``buffer`` (runs made before the choice existed). ConfigError for a value this
    version does not know."""
    if not config or config.get("protocol") is None:
        return BUFFER
    name = config["protocol"]
    require_choice(name, EpisodeProtocol, "protocol")
    if name == "offline":
        return PackingProtocol("offline")
    if name != "online":
        return BUFFER
    lookahead = config.get("lookahead", DEFAULT_LOOKAHEAD)
    return PackingProtocol("online", cast(int, lookahead))  # the value is checked on creation


__all__ = [
    "BUFFER",
    "DEFAULT_LOOKAHEAD",
    "MAX_LOOKAHEAD",
    "PackingProtocol",
    "saved_protocol",
]
