"""Candidate mode: the model picks one of K listed placements (docs/vlm.md).

Torch-free: :mod:`.states` (labelled states on disk), :mod:`.teachers`, :mod:`.collect`,
:mod:`.compose`. Torch side (the vlm extra): :mod:`.pointer`, :mod:`.train`, :mod:`.policy`.
"""
