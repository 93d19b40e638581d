"""SFT data for the packing VLM: step-level examples from a PackData export
(:mod:`.sft_examples`, no torch) and their encoding into model tensors (:mod:`.encoding`, vlm
extra)."""
