"""Local inference: prefix-cached greedy generation (:mod:`.generate`, vlm extra), the ``vlm`` and
``vlm-small`` policies (:mod:`.policy`, no torch at import) and their torch side
(:mod:`.runtime`)."""
