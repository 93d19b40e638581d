"""The packing VLM: prompt rendering and action parsing (pure, core install), and the model,
processing and training adapters (vlm extra: torch, transformers). Import submodules directly;
this package imports nothing so that ``import packlab.vlm`` never pulls torch."""
