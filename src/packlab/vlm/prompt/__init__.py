"""What the packing VLM reads and says: prompt rendering (:mod:`.render`), observation -> context
(:mod:`.context`) and answer parsing (:mod:`.parse`). Pure apart from drawing images; no torch."""
