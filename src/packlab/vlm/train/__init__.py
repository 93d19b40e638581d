"""Supervised fine-tuning of the packing VLM: the job's configuration (:mod:`.config`, no torch)
and the training loop (:mod:`.sft`, vlm extra)."""
