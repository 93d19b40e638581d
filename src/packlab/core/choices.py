"""Every named choice in one place, as ``Literal`` types.

Config dataclasses annotate their fields with these types, validation and the CLI read the
allowed values from them (:func:`choices`), so a choice list is written exactly once.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from typing import Literal, get_args

from packlab.core.errors import ConfigError

#: Transition backend: how a placed box settles (``geometric`` is exact Eq. 2, ``mujoco`` physics).
PhysicsBackend = Literal["mujoco", "geometric"]
#: Where independent work items (bench episodes, dataset shards) run.
Executor = Literal["process", "ray"]
#: What the VLM sees as each state's image.
ImageMode = Literal["heightmap", "blank", "none"]
#: How much of the episode's past the VLM context holds.
HistoryMode = Literal["full", "current_only", "no_actions"]
#: Bench and dataset difficulty levels (paper Table 1).
Difficulty = Literal["easy", "medium", "hard"]
#: The heuristic policies, in the paper's Table 2 order (their scorers:
#: ``packlab.policies.heuristics.SCORERS``, same names and order, checked by a test); here so that
#: the bench's default policy list is known without loading numpy.
Heuristic = Literal["dblf", "hm", "mta", "ffp", "sdf"]
HEURISTICS: tuple[str, ...] = get_args(Heuristic)
#: Heuristic tie rule between equally scored placements (docs/heuristics.md).
TieBreak = Literal["larger_volume", "shown_order"]
#: Layout family of generated cases: the paper's ``layered``, the opt-in richer ``stepped``,
#: ``random`` (independently drawn boxes, no perfect layout and no ``gt_plan``), ``cut`` (the
#: stack cuboid cut recursively, Zhao et al. 2021's CUT) or ``rs`` (i.i.d. boxes of the 64 types
#: with sides 2..5 units, their RS; no ``gt_plan``). docs/datagen.md.
LayoutFamily = Literal["layered", "stepped", "random", "cut", "rs"]
#: Arrival order of a generated case's objects: ``removal`` (reverse removal, any supported
#: order), ``layers`` (the reference benchmark's: layer by layer, shuffled within a layer), and
#: for ``cut`` layouts ``base-height`` (CUT-1: by base height, shuffled within one) or
#: ``support`` (CUT-2: drawn among the boxes whose footprint's surface stands at their base).
ArrivalOrder = Literal["removal", "layers", "base-height", "support"]
#: The ``plan`` policy's check of its chosen placement before committing it.
StabilityCheck = Literal["off", "support"]
#: The base policies that roll out the planner's first placements (``policies/plan/search.py``):
#: SDF-Pack's choice, the students' proposer's first listed placement (``lowest``), the
#: flush/contact ranking's first (``flush``); with several, a first placement costs the
#: cheapest of its rollouts.
RolloutBase = Literal["sdf", "lowest", "sdf+lowest", "sdf+lowest+flush"]
#: What a policy does when no shown box fits under the rim (``policies/overflow.py``): ``place``
#: the box that sticks out least (the literature's rule, every heuristic's default) or
#: ``score``: place one only where that raises the episode's Overall, else set one aside.
OverflowRule = Literal["place", "score"]
#: Which box of a guess the planner commits (``policies/plan/complete.commit_of``).
CommitRule = Literal["enclosed", "first"]
#: SFT export of a dataset: one multi-turn conversation per episode (packlab.datagen.sft_export),
#: or none.
SFTExport = Literal["episode", "none"]
#: The dtype a VLM's weights are built or loaded in (``packlab.vlm.model.spec.make_model``).
ModelDType = Literal["fp32", "bf16", "fp16"]
#: A pointer model's training precision (``packlab train candidate --dtype``): fp32, or bf16
#: autocast of the forward passes on a GPU while the weights and the optimizer stay float32.
AutocastDType = Literal["fp32", "bf16"]
#: How a bench episode failed (a failed record's ``error_kind``; docs/robustness.md): the policy
#: or engine raised (or its worker died), it ran past ``--episode-timeout``, or a remote
#: policy's server was unreachable.
ErrorKind = Literal["exception", "timeout", "transport"]

#: How a policy's answer names its action: the paper's free JSON object, or the index of one of
#: the placements listed by the candidate proposer (``packlab.policies.candidates``).
ActionFormat = Literal["json", "candidate"]
#: Round order of the candidate proposer (``packlab.policies.candidates``).
ProposerRule = Literal["lowest", "lowest+largest"]
#: Candidate mode's system turn: the full legend or one line (``packlab.vlm.candidate.compose``).
PromptInstructions = Literal["full", "short"]
#: How the candidate-mode pointer model sees the heightmap (``packlab.vlm.candidate.image``): as
#: an image through the vision tower, as the digit text map, both, or an all-zero image (the
#: blank-image ablation).
PointerMap = Literal["image", "text", "both", "blank"]
#: What each listed line of a candidate-mode prompt names (``packlab.vlm.candidate.compose``):
#: ``full``, its box, rotation, cell and the hand-computed geometry (resting height, support,
#: flushness, gap); ``cell``, its box, rotation and cell only.
LineFields = Literal["full", "cell"]
#: Who computes a learned policy's network outputs: ONNX Runtime (core install) or torch (extras).
LearnedRuntime = Literal["onnx", "torch"]
RUNTIMES: tuple[str, ...] = get_args(LearnedRuntime)
#: Who labels candidate-mode training states with a listed pick (packlab.policies.listed says
#: what each does); here so that `packlab train --help` lists them without loading the planner.
Teacher = Literal["plan", "plan-lookahead", "sdf", "mta", "oracle", "oracle-canonical", "first"]
TEACHERS: tuple[str, ...] = get_args(Teacher)

#: The RL agents of ``packlab train rl``: IR-BPP-style (choose one of K proposed placements) and
#: TAP-Net-style (choose which shown object; a fixed rule places it).
RLAgent = Literal["irbpp", "tapnet"]
#: How a TAP-Net-style agent's chosen box is placed: DBLF's rule, or the proposer's first listing
#: of that box (its lowest placement that leaves its level best, ``policies.candidates``). With
#: sides named longer first DBLF's rotation-0 preference no longer follows the layouts: placed by
#: DBLF, even the planner's own choice of box scores below the proposer (docs/rl.md).
TapnetPlacement = Literal["dblf", "proposer"]
DEFAULT_TAPNET_PLACEMENT: TapnetPlacement = "proposer"
#: What an agent card written before the field existed used.
UNRECORDED_TAPNET_PLACEMENT: TapnetPlacement = "dblf"
#: What an RL env pays per step: ``overall`` (potential-based, the change in Overall-so-far, so
#: the return is the final Overall), ``overall-terminal`` (0 until the last step, then Overall)
#: or ``success`` (the change in packed-volume fraction, return = Success Ratio, as Pack-v0).
RLReward = Literal["overall", "overall-terminal", "success"]
#: How an RL trainer runs its environment copies: one process each (``subproc``) or in-process.
VecKind = Literal["subproc", "dummy"]

#: What a policy observes: the exact heightmap and box sizes, or those perceived by
#: the simulated depth cameras (``packlab.sim.sensing``).
ObservationMode = Literal["exact", "perceived"]
#: How a chosen placement is executed: exactly, or with the robot noise of the ``NoisePreset``
#: (``packlab.sim.execution``; mujoco backend only).
ExecutionMode = Literal["exact", "noisy"]
#: Named sensor + robot noise levels: ``none`` (zero noise), ``structured-light`` (about 1 mm
#: depth noise), ``stereo`` (a consumer stereo camera, about 5-10 mm).
NoisePreset = Literal["none", "structured-light", "stereo"]
#: How perceived buffer objects are segmented (``packlab.sim.sensing``): from the ground-truth
#: per-pixel ids (the "SAM-perfect" setting) or by connected components above the table plane.
Segmentation = Literal["truth", "depth"]
#: What perceived observation assumes of box sizes (``packlab.sim.sensing.perception``):
#: ``grid`` snaps lengths and widths to the container's cell and heights to its height step
#: (the grids every generated case's sizes lie on: a prior of the generator, not of real
#: cartons); ``none`` reports the raw estimates rounded to whole millimetres.
SizePrior = Literal["grid", "none"]
DEFAULT_SIZE_PRIOR: SizePrior = "grid"
#: The sizes of a layout family's boxes (``packlab.datagen``): ``grid`` (every box fills its
#: cells of the layout exactly, sides on the grid) or ``off-grid`` (cartons: every box a drawn
#: clearance smaller than its slot; the perfect layout holds them with gaps).
CaseSizes = Literal["grid", "off-grid"]
#: How exact observations name a box's sides: longer side first, as perception names them (a
#: camera cannot see which side a catalogue calls l), or as the case's catalogue does (the
#: reference paper's protocol; its generator, like ours, names l after the side a box lies along
#: x in its perfect layout, a hint no robot has: 75 % of perfect placements use rotation 0).
SideNames = Literal["catalogue", "longer-first"]
#: The side names of every entry point that builds exact observations (bench, Gym and RL envs,
#: the data engine, the VLM and candidate state builders, scripts): no orientation hint.
DEFAULT_SIDES: SideNames = "longer-first"
#: What a run or dataset recorded before side names were part of its identity used: the
#: catalogue's names (an absent ``sides`` key reads as this, so an old run is never resumed or
#: replayed under other names).
UNRECORDED_SIDES: SideNames = "catalogue"
#: Whether observations carry ``remaining`` (boxes still to come, shown ones included): an
#: extension of the reference's observation, which has no such field; a robot cell knows its
#: order's size. ``hidden`` (None in the observation) is the ablation without it.
RemainingMode = Literal["shown", "hidden"]
DEFAULT_REMAINING: RemainingMode = "shown"
#: The episode's protocol: packlab's ``buffer`` (the first k boxes shown shuffled, any may be
#: placed, every box processed) or the field's ``online`` (the next k boxes shown in arrival
#: order, the first must be placed; BPP-1 at k = 1, BPP-k above; the episode ends at the first
#: box that fits nowhere), or the ``offline`` reference (every box shown, any may be placed).
#: ``packlab.core.packing_protocol`` holds the rule.
EpisodeProtocol = Literal["buffer", "online", "offline"]
DEFAULT_PROTOCOL: EpisodeProtocol = "buffer"


def own_rotation(size: tuple[int, int, int], rotation: int, sides: SideNames) -> int:
    """The box's own rotation (of its catalogue sides) that does what a policy's ``rotation``
    of the sides it was shown under ``sides`` does (see :func:`named_size`)."""
    l, w, _ = size
    return rotation ^ int(sides == "longer-first" and l < w)


def named_size(size: tuple[int, int, int], sides: SideNames) -> tuple[int, int, int]:
    """A box's catalogue (l, w, h) as exact observation under ``sides`` names it: rotation r of
    the named box is rotation ``r ^ 1`` of the catalogue's where the names differ (l < w)."""
    l, w, h = size
    return (max(l, w), min(l, w), h) if sides == "longer-first" else (l, w, h)


#: The noise preset when none is named: an industrial structured-light camera, the usual
#: sensor of a bin-packing cell.
DEFAULT_NOISE: NoisePreset = "structured-light"
#: How perceived mode tells the buffer's boxes apart unless told: from depth, as a robot must.
DEFAULT_SEGMENTATION: Segmentation = "depth"


def choices(choice_type: object) -> tuple[str, ...]:
    """The allowed values of a ``Literal`` choice type, in declaration order."""
    values = get_args(choice_type)
    if not values:
        raise TypeError(f"{choice_type!r} is not a Literal choice type")
    return values


def did_you_mean(value: object, names: Iterable[object]) -> str:
    """``" (did you mean 'dblf'?)"`` for the name closest to a misspelt ``value``, else ``""``."""
    if not isinstance(value, str):
        return ""
    close = difflib.get_close_matches(value, [str(n) for n in names], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def require_choice(value: object, choice_type: object, field: str) -> None:
    """Raise ``ConfigError`` naming ``field`` when ``value`` is not one of the type's values."""
    allowed = choices(choice_type)
    if value not in allowed:
        raise ConfigError(
            f"{field} = {value!r}: unknown{did_you_mean(value, allowed)}; "
            f"choose one of {', '.join(allowed)}"
        )
