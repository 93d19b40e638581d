"""PlanPolicy: the Policy protocol over completion and lookahead, and the ``plan`` factory.

A decision first asks :mod:`.complete` for a tiling of the lowest free level by shown boxes of
one height (exact, or with rectangles left for boxes not yet seen); when one exists its first
box is the action. Otherwise the lookahead (:mod:`.search`) decides.

Sees only its observation: the heightmap, the shown buffer and the history (for the sizes of
the boxes seen so far). Deterministic for a given budget; the run seed is accepted and ignored.
With ``time_s`` set the search stops after the depth that passes it, so results then depend on
the machine's speed (documented as not bit-reproducible).

Factory keywords (``packlab bench --policy-arg plan:first=4``): ``first``, ``listed``,
``depth``, ``beam``, ``time_s``, ``rollout`` (see :class:`.search.Budget`), the cost weights
``w_trapped``, ``w_unreachable``, ``w_open``, ``w_steps``, ``w_over_rim``, ``w_final`` (see
:class:`.evaluate.Weights`) and
``stability`` (``off`` or ``support``: take the cheapest placement whose centre is over its
support, :mod:`.stability`; ``decisions`` and ``fallbacks`` count how often that changed the
choice), ``overflow`` (``score``, the default, or ``place``: what to do when no shown box fits
under the rim, :mod:`packlab.policies.overflow`; ``overflowed`` counts those decisions), and
for the completion ``complete`` (true/false), ``nodes``, ``decision_nodes``,
``jokers``, ``joker_seen``, ``guesses``, ``mixed_jokers``, ``mixed_evidence`` (see
:class:`.complete.CompletionConfig`;
``completed`` counts the decisions it took), and ``guide`` (``none``, the default, ``irbpp`` or
``tapnet``), ``guide_model`` (that agent's directory; default the shipped one) and
``guide_first`` (default 2): a trained agent's preferred placements rolled out by the
lookahead beside its own (:mod:`.guide`), ``finale`` (true/false) with ``finale_boxes``
(default 8): the last boxes' set-aside rule and the most boxes in view it decides for
(:mod:`.finale`), and ``endplay`` (first actions tried besides the planner's once every box
still to come is in view, each followed by the planner's own play to the end; 0 turns it off)
with ``endplay_boxes`` (the most boxes in view for it) (:mod:`.endplay`).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from packlab.core.choices import (
    CommitRule,
    OverflowRule,
    RolloutBase,
    StabilityCheck,
    require_choice,
)
from packlab.core.errors import ConfigError
from packlab.core.feasibility import observation_candidates
from packlab.core.protocols import EpisodeStart
from packlab.core.types import Action, Observation
from packlab.policies.overflow import overflow_decision
from packlab.policies.plan.complete import Completion, CompletionConfig, find_completion
from packlab.policies.plan.cover import Slot
from packlab.policies.plan.endgame import Endgame, EndgameConfig
from packlab.policies.plan.endplay import BasePlayer, Endplay, EndplayConfig
from packlab.policies.plan.evaluate import Weights, smallest_footprints
from packlab.policies.plan.finale import FINALE_BOXES, with_finale
from packlab.policies.plan.guide import AgentGuide
from packlab.policies.plan.outlook import observation_outlook
from packlab.policies.plan.placed import with_own_placements
from packlab.policies.plan.proposer import first_placements
from packlab.policies.plan.search import Budget, Problem, search
from packlab.policies.registry import SeedFreeMode, declare_seed_free


def observation_problem(observation: Observation, weights: Weights) -> Problem:
    """The search problem of one step: the shown objects, the container, and the smallest
    footprints seen so far (history included) for the cost's unfillable-gap term."""
    items = [s for h in observation.history for s in h.shown] + list(observation.shown)
    return Problem(
        observation.shown,
        observation.container.height_mm,
        observation.container.cell_xy_mm,
        smallest_footprints([(s.size_cells[0], s.size_cells[1]) for s in items]),
        weights,
        in_order=observation.must_place_first,
        # The outlook walks the whole history; without its weight nothing reads it.
        outlook=observation_outlook(observation) if weights.final else None,
    )


@dataclass(frozen=True, slots=True)
class PlanDecision:
    """One decision and where it came from: the tiling it commits the first box of (None when
    the lookahead decided). A teacher reads the tiling's other boxes as equally good first
    placements (every box of it rests on the same level)."""

    action: Action
    completion: Completion | None


@dataclass
class PlanPolicy:
    """Receding-horizon lookahead: search, commit the first placement, observe, repeat."""

    budget: Budget = field(default_factory=Budget)
    weights: Weights = field(default_factory=Weights)
    stability: StabilityCheck = "off"
    name: str = "plan"
    #: Since construction: decisions taken, and those where the cheapest placement failed the
    #: stability check and a supported one (or, with none, the cheapest anyway) was taken.
    decisions: int = 0
    fallbacks: int = 0
    #: Exact completion of the lowest free region first (``complete=off``: the lookahead alone).
    complete: bool = True
    completion: CompletionConfig = field(default_factory=CompletionConfig)
    #: Decisions taken from a completion (the rest from the lookahead).
    completed: int = 0
    #: With every remaining box in view, an exact filling of the rest (``endgame_nodes=0``: off).
    endgame: Endgame = field(default_factory=Endgame)
    #: When no shown box fits under the rim (or the episode's last box would raise the top):
    #: ``score`` places one only where that raises the episode's Overall and otherwise sets
    #: one aside; ``place`` takes the lookahead's choice among the boxes sticking out least
    #: (:mod:`packlab.policies.overflow`).
    overflow: OverflowRule = "score"
    #: Decisions taken by the ``score`` overflow rule.
    overflowed: int = 0
    #: A trained agent whose preferred placements the lookahead rolls out too (:mod:`.guide`).
    guide: AgentGuide = field(default_factory=AgentGuide)
    #: With every remaining box in view, set one aside where that ends the episode higher than
    #: the lookahead's placement, which raises the top (:mod:`.finale`; with ``overflow=score``
    #: only).
    finale: bool = True
    #: The most boxes in view for which the finale decides (:data:`.finale.FINALE_BOXES`).
    finale_boxes: int = FINALE_BOXES
    #: Decisions the finale turned into a set-aside.
    finales: int = 0
    #: With every remaining box in view, other first actions played out by the planner itself
    #: (:mod:`.endplay`; with ``overflow=score`` only).
    endplay: Endplay = field(default_factory=Endplay)
    #: Decisions the endplay changed.
    endplays: int = 0

    def reset(self, start: EpisodeStart, seed: int) -> None:
        """Forget the last episode's filling (the planner is handed no case, only its start)."""
        self.endgame.reset()
        self.endplay.reset()

    def act(self, observation: Observation) -> Action:
        return self.decide(observation).action

    def decide(self, observation: Observation) -> PlanDecision:
        """The action and, when a completion decided it, the tiling (see :class:`PlanDecision`)."""
        decision = self._decide_stages(observation)
        if self.overflow != "score" or not self.endplay.applies(observation):
            return decision
        action = self.endplay.decide(observation, decision.action, self._base_player)
        if action == decision.action:
            return decision
        self.endplays += 1
        return PlanDecision(action, None)

    def _base_player(self) -> BasePlayer:
        """A copy of this planner, the endplay off, playing on from a simulated observation (a
        copy: its endgame filling and counters must not touch this one's)."""
        kept, self.endplay = self.endplay, Endplay(EndplayConfig(alternatives=0))
        try:
            twin = copy.deepcopy(self)
        finally:
            self.endplay = kept
        return lambda observation: twin._decide_stages(observation).action

    def _decide_stages(self, observation: Observation) -> PlanDecision:
        """Endgame, completion, overflow, lookahead and finale, in that order."""
        if self.complete:
            # The endgame builds its filling in its own order; the online protocol fixes the
            # order, so there the endgame stays out (the completion and the search adapt).
            filling = None if observation.must_place_first else self.endgame.act(observation)
            if filling is not None:
                self.decisions += 1
                self.completed += 1
                return PlanDecision(filling, None)
            found = self._completion(observation)
            slot = None if found is None else committed_slot(found, observation)
            if slot is not None:
                self.decisions += 1
                self.completed += 1
                action = Action(object_id=slot.key, rotation=slot.rotation, x=slot.x, y=slot.y)
                return PlanDecision(action, found)
        cands = observation_candidates(observation)
        overflow = overflow_decision(observation, cands, self.overflow)
        if overflow is not None:
            self.decisions += 1
            self.overflowed += 1
            return PlanDecision(overflow, None)
        problem = observation_problem(observation, self.weights)
        firsts = None
        if self.guide.active:
            firsts = first_placements(cands, self.budget.first, self.budget.listed)
            firsts += [i for i in self.guide.placements(observation, cands) if i not in firsts]
        outcome = search(
            observation.heightmap,
            problem,
            self.budget,
            check_support=self.stability == "support",
            firsts=firsts,
            candidates=cands,
        )
        self.decisions += 1
        self.fallbacks += int(outcome.fell_back)
        first = outcome.placement
        if first is None:  # nothing fits the floor: an out-of-bounds step sets object 0 aside
            return PlanDecision(Action(object_id=0, rotation=0, x=0, y=0), None)
        action = Action(first.object_index, first.rotation, first.x, first.y)
        # The finale is the ``score`` overflow rule's comparison carried to the last boxes in
        # view; ``overflow=place`` (never set a box aside) turns it off with the rest of it.
        final = (
            with_finale(observation, action, self.overflow, self.finale_boxes)
            if self.finale
            else action
        )
        self.finales += int(final != action)
        return PlanDecision(final, None)

    def _completion(self, observation: Observation) -> Completion | None:
        seen = [s for h in observation.history for s in h.shown] + list(observation.shown)
        prior = -(-self.completion.smallest_side_mm // observation.container.cell_xy_mm)
        smallest_side = min(prior, *(min(s.size_cells[:2]) for s in seen))
        # Boxes still to come: hidden (``--remaining hidden``), as many as a guess may leave
        # room for, i.e. more may always come.
        unseen = (
            self.completion.max_jokers
            if observation.remaining is None
            else observation.remaining - len(observation.shown)
        )
        return find_completion(
            # Its own boxes' edges that a cell-centre reading lost, read back (.placed).
            with_own_placements(observation),
            observation.shown,
            observation.container.height_mm,
            unseen,
            smallest_side,
            seen_heights(observation),
            self.completion,
        )


def committed_slot(found: Completion, observation: Observation) -> Slot | None:
    """The box of a tiling to place now: its commit (:func:`.complete.commit_of`), or (online
    protocol) the first shown box's slot; None when the tiling leaves that box out, so the
    search decides. Every box of a tiling rests on the same level, so any may go first."""
    if not observation.must_place_first:
        return found.commit
    return next((s for s in found.slots if observation.placeable(s.key)), None)


def seen_heights(observation: Observation) -> list[int]:
    """The height of every box seen so far, each box once: the one each past step processed and
    those shown now. Not by id: perceived mode shows fresh ids at every observation, and a box
    waiting in the buffer is seen again at every step."""
    processed = [
        h.shown[h.action.object_id].size_mm[2]
        for h in observation.history
        # A step processes the box it names even when it sets it aside (out of bounds).
        if isinstance(h.action, Action) and 0 <= h.action.object_id < len(h.shown)
    ]
    return processed + [s.size_mm[2] for s in observation.shown]


_BUDGET_KEYS = {f.name for f in fields(Budget)}
_WEIGHT_KEYS = {f"w_{f.name}": f.name for f in fields(Weights)}
#: Options of the completion stage: ``nodes`` (node budget of one exact-cover search),
#: ``decision_nodes`` (of all of one decision's searches together), ``jokers`` (most
#: rectangles a guess leaves for unseen boxes), ``joker_seen`` (how often a height must have
#: been seen before a guess is made for it), ``guesses`` (tilings a guess compares),
#: ``mixed_jokers`` and ``mixed_evidence`` (a mixed-height tiling's guesses: how many rectangles,
#: and the share of seen boxes repeating a height they need).
_COMPLETION_KEYS = {
    "nodes": "max_nodes",
    "decision_nodes": "decision_nodes",
    "jokers": "max_jokers",
    "joker_seen": "joker_min_seen",
    "guesses": "guesses",
    "mixed_jokers": "mixed_jokers",
    "mixed_evidence": "mixed_evidence",
}
#: Completion options that are a share in [0, 1] (the rest are whole numbers).
_SHARE_KEYS = ("mixed_evidence",)
#: The finale's limit (:data:`.finale.FINALE_BOXES`): at most this many boxes in view.
_FINALE_KEYS = ("finale_boxes",)
#: Options of the endgame (:class:`.endgame.EndgameConfig`): ``endgame_nodes`` (node budget
#: of one skyline search; 0 turns it off), ``endgame_boxes`` (most boxes in view for it),
#: ``guillotine_nodes`` (node budget of one guillotine assembly on a flat surface; 0 turns it
#: off) and ``guillotine_boxes`` (most boxes in view for it).
_ENDGAME_KEYS = {
    "endgame_nodes": "max_nodes",
    "endgame_boxes": "max_boxes",
    "guillotine_nodes": "guillotine_nodes",
    "guillotine_boxes": "guillotine_boxes",
}
#: ``complete`` (the completion stage at all), ``mixed`` (its last stage: a tiling of mixed
#: heights, :attr:`.complete.CompletionConfig.mixed`) and ``finale`` (:mod:`.finale`).
_SWITCHES = ("complete", "mixed", "finale")
_WHOLE_KEYS = ("nodes", "decision_nodes", "guesses")  # the rest may be 0
#: The agent guiding the lookahead (:class:`.guide.AgentGuide`: agent, model, first).
_GUIDE_KEYS = ("guide", "guide_model", "guide_first")
#: Options of the endplay (:class:`.endplay.EndplayConfig`): ``endplay`` (first actions tried
#: besides the planner's; 0 turns it off) and ``endplay_boxes`` (most boxes in view for it).
_ENDPLAY_KEYS = {"endplay": "alternatives", "endplay_boxes": "max_boxes"}


def _whole(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"plan: {name} = {value!r}: must be a whole number >= 1")
    return value


def _count(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"plan: {name} = {value!r}: must be a whole number >= 0")
    return value


def _share(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1:
        raise ConfigError(f"plan: {name} = {value!r}: must be a number from 0 to 1")
    return float(value)


def _completion_option(name: str, value: Any) -> int | float:
    if name in _SHARE_KEYS:
        return _share(name, value)
    return _whole(name, value) if name in _WHOLE_KEYS else _count(name, value)


def _switch(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"plan: {name} = {value!r}: must be true or false")
    return value


def plan_seed_free(options: Mapping[str, Any]) -> frozenset[SeedFreeMode]:
    """Where the planner plays the same episode for every run seed (``registry.SeedFreeMode``):
    in arrival order, where it reads nothing of the seed, unless ``time_s`` makes its search
    depend on the machine's speed. Never under a shuffled buffer: its search settles equal
    costs in the order the boxes are shown."""
    return frozenset() if options.get("time_s") is not None else frozenset({"arrival"})


@declare_seed_free(plan_seed_free)
def make_plan(**options: Any) -> PlanPolicy:
    """The ``plan`` policy; keywords as in the module docstring."""
    guide = AgentGuide(
        options.pop("guide", "none"),
        options.pop("guide_model", None),
        options.pop("guide_first", 2),
    )
    stability = options.pop("stability", "off")
    require_choice(stability, StabilityCheck, "plan: stability")
    overflow = options.pop("overflow", "score")
    require_choice(overflow, OverflowRule, "plan: overflow")
    commit = options.pop("commit", "enclosed")
    require_choice(commit, CommitRule, "plan: commit")
    option_keys = (
        _WEIGHT_KEYS,
        _COMPLETION_KEYS,
        _ENDGAME_KEYS,
        _SWITCHES,
        _FINALE_KEYS,
        _ENDPLAY_KEYS,
    )
    known_keys = _BUDGET_KEYS.union(*option_keys)
    unknown = sorted(set(options) - known_keys)
    if unknown:
        extra = {"stability", "overflow", "commit", *_GUIDE_KEYS}
        known = ", ".join(sorted(known_keys | extra))
        raise ConfigError(f"plan: unknown option {unknown[0]!r}; options: {known}")
    budget = Budget(**{k: v for k, v in options.items() if k in _BUDGET_KEYS})
    weights = Weights(
        **{_WEIGHT_KEYS[k]: float(v) for k, v in options.items() if k in _WEIGHT_KEYS}
    )
    for name in ("first", "depth", "beam"):
        _whole(name, getattr(budget, name))
    _count("listed", budget.listed)
    require_choice(budget.rollout, RolloutBase, "plan: rollout")
    if budget.time_s is not None and not budget.time_s > 0:
        raise ConfigError(f"plan: time_s = {budget.time_s!r}: must be > 0")
    # Whole numbers and shares by key (_completion_option checked each); Any for mypy.
    completion_values: dict[str, Any] = {
        _COMPLETION_KEYS[k]: _completion_option(k, v)
        for k, v in options.items()
        if k in _COMPLETION_KEYS
    }
    completion = CompletionConfig(
        **completion_values,
        mixed=_switch("mixed", options.get("mixed", True)),
        commit=commit,
    )
    endgame = EndgameConfig(
        **{_ENDGAME_KEYS[k]: _count(k, v) for k, v in options.items() if k in _ENDGAME_KEYS}
    )
    switches = {k: _switch(k, options[k]) for k in _SWITCHES if k in options}
    endplay = EndplayConfig(
        **{_ENDPLAY_KEYS[k]: v for k, v in options.items() if k in _ENDPLAY_KEYS}
    )
    return PlanPolicy(
        budget,
        weights,
        stability,
        complete=switches.get("complete", True),
        completion=completion,
        endgame=Endgame(endgame),
        overflow=overflow,
        guide=guide,
        finale=switches.get("finale", True),
        finale_boxes=_whole("finale_boxes", options.get("finale_boxes", FINALE_BOXES)),
        endplay=Endplay(endplay),
    )


#: ``plan-fast``'s budget: the sweep's point that keeps the default ``packlab bench`` (which runs
#: it) under five minutes on two cores (docs/planner.md). Two of the students' listed placements:
#: with the final-height shortfall scoring the rollouts they gained +0.006 [+0.003, +0.009] over
#: none on 588 generated training cases (four gained +0.004 [-0.000, +0.008] and cost more
#: time); without that term they change no family's score. No endplay: it was measured for
#: ``plan`` only, and it multiplies the last steps' time.
FAST_BUDGET = {"first": 2, "depth": 4, "listed": 2, "endplay": 0}


@declare_seed_free(plan_seed_free)
def make_plan_fast(**options: Any) -> PlanPolicy:
    """``plan`` at :data:`FAST_BUDGET` (keywords as for ``plan`` override it)."""
    policy = make_plan(**{**FAST_BUDGET, **options})
    policy.name = "plan-fast"
    return policy


@declare_seed_free(plan_seed_free)
def make_plan_lookahead(**options: Any) -> PlanPolicy:
    """``plan`` without the completion stage: the lookahead alone (an ablation row: what the
    completion search adds)."""
    policy = make_plan(**{"complete": False, **options})
    policy.name = "plan-lookahead"
    return policy
