"""The same states labelled by another teacher (the teacher ablation: only the label changes).

The state's observation is rebuilt from the file without its history; no teacher here reads the
history except the planner's smallest-footprint estimate, so relabelling with ``plan`` is close
to but not exactly what collection gives, and the other teachers are exact.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping

import msgspec

from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Case
from packlab.policies.listed import ListedTeacher
from packlab.vlm.candidate.states import LabelledState, listed_of, observation_of


def relabel(
    states: Iterable[LabelledState], teacher: str, cases: Mapping[str, Case]
) -> Iterator[LabelledState]:
    """Each state with ``teacher``'s pick among its listed placements (-1: not listed)."""
    labeller = ListedTeacher(teacher)
    current = None
    for s in states:
        if s.case_id != current:
            if s.case_id not in cases:
                raise ConfigError(f"relabel: case {s.case_id!r} of the states is not given")
            labeller.reset(cases[s.case_id], 0)
            current = s.case_id
        obs = observation_of(s)
        label = labeller.choose(obs, observation_candidates(obs), listed_of(s))
        yield msgspec.structs.replace(s, teacher=teacher, label=label)
