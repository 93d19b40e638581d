"""packlab: closed-loop robotic bin packing with physics, data, heuristics, bench and VLMs."""

__version__ = "0.1.0"
