"""``plan``: a receding-horizon lookahead planner over the shown buffer (docs/planner.md)."""
