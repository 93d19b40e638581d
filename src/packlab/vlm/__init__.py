"""The packing VLM, one subpackage per job:

- :mod:`packlab.vlm.prompt`: what the model reads and says (prompt rendering, observation ->
  context, parsing answers); pure, core install;
- :mod:`packlab.vlm.data`: SFT examples read from a PackData export (core install) and their
  encoding into model tensors (vlm extra);
- :mod:`packlab.vlm.model`: the Qwen-VL-family model bundle, checkpoints, tiny random-weight
  models and their tokenizer (vlm extra);
- :mod:`packlab.vlm.train`: the SFT configuration (core install) and training loop (vlm extra);
- :mod:`packlab.vlm.infer`: prefix-cached greedy generation and the local ``vlm`` policies;
- :mod:`packlab.vlm.serve`: the ``endpoint`` policy (an OpenAI-compatible client, stdlib only)
  and a small OpenAI-compatible server.

Import modules directly: no package here imports anything, so that ``import packlab.vlm...``
never pulls torch unless the module named needs it (:mod:`packlab.vlm.extra`).
"""
