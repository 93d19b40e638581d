"""Qwen-VL-family models (vlm extra): the :class:`~.checkpoint.VLM` bundle and checkpoint
directories (:mod:`.checkpoint`), tiny random-weight models (:mod:`.tiny`), the project's own
tokenizer (:mod:`.tokenizer`) and model specs (:mod:`.spec`)."""
