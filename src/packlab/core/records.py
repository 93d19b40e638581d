"""Typed, versioned records on disk (DESIGN.md section 6): bench episodes, summaries, dataset info.

Why msgspec: one small, dependency-free library that gives frozen typed ``Struct``s, strict
validation and fast JSON encode/decode in one call. pydantic is heavier and slower for
per-episode records (a bench run writes thousands, each with every step of the episode).

Every record carries its format version and every reader checks it first:

=====================  ===============================  =========================================
record (file)          version field = current value    older versions
=====================  ===============================  =========================================
episode record         ``format`` = ``RUN_FORMAT``      records written before records carried
(``episodes.jsonl``)   (``packlab-bench-run-2``, the    ``format`` (run-1 and early run-2) are
                       run directory's format)          migrated: see ``migrate_episode``
run summary            ``format`` = ``SUMMARY_FORMAT``  summaries without ``format`` are migrated:
(``summary.json``)     (``packlab-bench-summary-1``)    see ``migrate_summary``
run config, the part   ``format``, one of               run-1 directories are read (their records
a report reads         ``RUN_FORMATS``                  migrate); resuming them is refused by
(``config.json``)                                       ``packlab.bench.config.check_resumable``
dataset info           ``format_version`` =             ``packdata-1`` (its SFT export was one
(``meta/info.json``)   ``PACKDATA_FORMAT``              JSONL example per step) is read as is;
                                                        ``packlab export sft`` rewrites its export;
                                                        a file without the field is refused
=====================  ===============================  =========================================

Any other version (a newer packlab wrote it, or the file is not ours) is a ``RecordFormatError``
naming the file, the field and the value; so is a field of the wrong type or a missing one
(``decode_episode`` and the other readers: file, line of a JSONL file, dotted field path,
value). Unknown extra fields are ignored.

Writing: ``to_builtins`` then the standard ``json`` module, exactly as before these types, so
files stay byte-identical (msgspec's own float format differs: ``1e-6`` for Python's ``1e-06``).
Reading uses msgspec's decoder (correctly rounded floats: the same values ``json`` gives).

Case rows are not here: ``packlab.cases`` reads the reference's own format (no version field in
it to check, frozen suites under checksums) with its own file/line/field/value messages.
"""

from __future__ import annotations

import json
import re
import threading
from typing import ClassVar, Literal, TypeVar

import msgspec
from msgspec import UNSET, Struct, UnsetType

from packlab.core.choices import ErrorKind
from packlab.core.errors import RecordFormatError
from packlab.core.types import Action, Unparsable

# -- versions ----------------------------------------------------------------------------------

#: Version of the bench run directory (config.json) and of each of its episode records.
#: 2: error records carry ``error_kind``, episode records say whether the boxes were at
#: rest when scored, and heuristics break ties by the larger object unless told otherwise. A
#: run-1 directory therefore cannot be resumed (its heuristic episodes were played under the old
#: tie rule); the identity check refuses it by this field. Reports still read run-1 records.
#: Episode records carry this value in their ``format`` field (an added key, which every
#: earlier reader ignores, so the version stays 2). Steps carry their boxes' pose changes in
#: ``poses`` (an added key likewise; see ``StepRecord.poses``).
RUN_FORMAT = "packlab-bench-run-2"
RUN_FORMAT_1 = "packlab-bench-run-1"
#: Run-directory formats a report reads (the records of run-1 migrate; see ``migrate_episode``).
RUN_FORMATS = (RUN_FORMAT_1, RUN_FORMAT)
#: Version of ``summary.json``. Summaries written before it carried one are migrated.
SUMMARY_FORMAT = "packlab-bench-summary-1"
#: Version of a PackData directory (``meta/info.json`` ``format_version``); bump when a file's
#: layout or a column's meaning changes. packdata-2: the SFT export is one Parquet conversation per
#: episode (``packlab.datagen.sft_export``); packdata-1 wrote JSONL, one example per step.
PACKDATA_FORMAT = "packdata-2"
#: PackData versions this code reads (steps and episodes did not change between them).
PACKDATA_FORMATS = ("packdata-1", PACKDATA_FORMAT)

# -- JSON values -------------------------------------------------------------------------------

#: A JSON leaf. Free-form parts of records (resolved configs) are JSON values, not ``Any``:
#: msgspec validates them too. Nesting is spelled out to six levels (msgspec takes no recursive
#: alias on Python 3.11), deeper than any config written.
JsonScalar = str | int | float | bool | None
_Json1 = JsonScalar | list[JsonScalar] | dict[str, JsonScalar]
_Json2 = JsonScalar | list[_Json1] | dict[str, _Json1]
_Json3 = JsonScalar | list[_Json2] | dict[str, _Json2]
_Json4 = JsonScalar | list[_Json3] | dict[str, _Json3]
_Json5 = JsonScalar | list[_Json4] | dict[str, _Json4]
JsonValue = JsonScalar | list[_Json5] | dict[str, _Json5]
JsonObject = dict[str, JsonValue]

#: An object's id as the case file gives it (the reference's ids are strings).
RecordId = int | str

#: A box's logged pose at a step: object index, centre (mm), quaternion (w, x, y, z).
PoseEntry = tuple[int, float, float, float, float, float, float, float]


# -- episode records (episodes.jsonl) ---------------------------------------------------------


class ActionRecord(Struct, frozen=True):
    """A step's action: a placement ``{object_id, x, y, rotation}`` or, for model output that
    did not parse, ``{unparsable, error}``; exactly one of the two forms."""

    object_id: int | UnsetType = UNSET
    x: int | UnsetType = UNSET
    y: int | UnsetType = UNSET
    rotation: int | UnsetType = UNSET
    unparsable: str | UnsetType = UNSET
    error: str | UnsetType = UNSET

    def __post_init__(self) -> None:
        placement = [v is UNSET for v in (self.object_id, self.x, self.y, self.rotation)]
        text = [v is UNSET for v in (self.unparsable, self.error)]
        if not ((not any(placement) and all(text)) or (all(placement) and not any(text))):
            raise ValueError(
                "an action is either {object_id, x, y, rotation} or {unparsable, error}"
            )

    @classmethod
    def of(cls, action: Action | Unparsable) -> ActionRecord:
        if isinstance(action, Action):
            return cls(object_id=action.object_id, x=action.x, y=action.y, rotation=action.rotation)
        return cls(unparsable=action.text, error=action.error)

    def placement(self) -> tuple[int, int, int, int] | None:
        """(object_id, rotation, x, y) of a placement; None for the ``{unparsable, error}`` form."""
        o, r, x, y = self.object_id, self.rotation, self.x, self.y
        if isinstance(o, int) and isinstance(r, int) and isinstance(x, int) and isinstance(y, int):
            return o, r, x, y
        return None

    def to_action(self) -> Action | Unparsable:
        if isinstance(self.unparsable, str):
            return Unparsable(self.unparsable, self.error if isinstance(self.error, str) else "")
        fields = self.placement()
        assert fields is not None  # __post_init__ checked the form
        return Action(*fields)


class PerceptionErrors(Struct, frozen=True):
    """A step's perception errors (``packlab.sim.replan.Perception``), shown order."""

    #: Per object; None for an object perception missed (it was set aside, never shown).
    dims_error_mm: tuple[float | None, ...]  # largest |estimated - true| of (l, w, h)
    yaw_error_deg: tuple[float | None, ...]  # |estimated - true| yaw of the long axis
    heightmap_mae_mm: float | None  # mean |perceived - exact| over the container's cells
    scans: int | UnsetType = UNSET  # looks at the buffer (2: one re-scan); absent in old runs


#: How a step's text answer was read (``StepRecord.format_event``): the whole answer (after any
#: reasoning) was the JSON action, the action was found inside other text (a code fence, words
#: around it), or no action could be read.
FormatEvent = Literal["strict_json", "extra_text", "parse_fail"]
FORMAT_EVENTS: tuple[FormatEvent, ...] = ("strict_json", "extra_text", "parse_fail")


class StepRecord(Struct, frozen=True):
    """One step of an episode (``packlab.sim.episode.StepResult.to_record``)."""

    step: int
    action: ActionRecord
    valid: bool
    reason: str  # "" when valid, else one of packlab.sim.episode.INVALID_REASONS
    internal_id: RecordId  # the object processed (placed or set aside)
    shown: tuple[RecordId, ...]  # internal ids of the buffer in the order shown
    drop_mm: tuple[int, int, int] | None  # footprint min corner and Eq. 2 height; None if invalid
    settle_steps: int
    settled: bool  # False: the placement's settle hit its step cap
    max_linear_speed_mps: float
    max_angular_speed_radps: float
    wall_time_s: float
    #: The boxes placed or moved at this step (``packlab.sim.pose_log``): ``(object index into
    #: the case's objects, x, y, z centre mm to 0.1, qw, qx, qy, qz to 1e-4)`` for each box whose
    #: settled pose differs from the last one written for it by more than 0.5 mm or 1e-3; the
    #: poses after a step are the latest written. An added key (the version stays run-2);
    #: absent from older records (a replay then rebuilds them from ``drop_mm`` on
    #: the geometric backend, or shows final poses only; ``packlab.viz.report_data``).
    poses: tuple[PoseEntry, ...] | UnsetType = UNSET
    #: Perceived observation only (added keys, the version stays): the perceived
    #: heightmap after this step departed from its Eq. 2 prediction (a re-plan event).
    replan: bool | UnsetType = UNSET
    #: Noisy execution only: the executed drop's deviation from the planned one,
    #: (dx mm, dy mm, extra yaw degrees, release height mm).
    executed: tuple[float, float, float, float] | UnsetType = UNSET
    #: Perceived observation only: errors of the perception this step decided on.
    perception: PerceptionErrors | UnsetType = UNSET
    #: The policy's ``act`` for this step, wall seconds and CPU seconds of the whole
    #: process (every thread of a model runtime counts). Written by ``run_episode`` (the bench,
    #: the data engine's teachers); absent from older records and from steps driven by other
    #: loops (the Gymnasium env), which time no decision.
    decision_s: float | UnsetType = UNSET
    decision_cpu_s: float | UnsetType = UNSET
    #: Noisy execution only: what the place skill had to do for this placement, the
    #: nonzero counts by kind (``packlab.sim.physics.place_skill.SkillReport``); absent from
    #: older records and from steps placed exactly.
    skill: dict[str, int] | UnsetType = UNSET
    #: Policies that read a model's text answer (the ``last_answer_format`` hook, DESIGN.md
    #: section 7), added keys (the version stays run-2): how this step's answer was read;
    #: ``reasked``, whether it was asked for a second time (present where the policy re-asks
    #: an unusable answer); ``forced``, why a forced set-aside replaced the answer
    #: (``parse_fail`` or ``invalid_object_id``; present only where one did). Absent from other
    #: policies' steps, from steps whose request got no answer at all (a refused request) and
    #: from older records.
    format_event: FormatEvent | UnsetType = UNSET
    reasked: bool | UnsetType = UNSET
    forced: str | UnsetType = UNSET


class MetricsRecord(Struct, frozen=True):
    """An episode's scores and counters (``packlab.metrics.EpisodeMetrics.to_dict``)."""

    success_ratio: float
    compactness: float
    overall: float
    inside_volume_mm3: int
    total_volume_mm3: int
    max_height_mm: int
    n_objects: int
    n_inside: int
    n_set_aside: int
    invalid_by_reason: dict[str, int]
    settle_steps: int
    unsettled_steps: int
    final_settle_steps: int
    at_rest: bool
    residual_linear_mps: float
    residual_angular_radps: float
    wall_time_s: float
    #: Perceived observation only: steps with a re-plan event.
    replans: int | UnsetType = UNSET
    #: Perceived observation only: objects perception did not find (set aside, not packed).
    missed: int | UnsetType = UNSET
    #: Perceived observation only, where it happened: times an object was not found and left in
    #: the buffer for another look at the next observation (``sim.episode.LOOKS_BEFORE_SET_ASIDE``).
    looked_again: int | UnsetType = UNSET
    #: Noisy execution only: the place skill's counts summed over the episode's
    #: steps, by kind; absent from older records.
    skill: dict[str, int] | UnsetType = UNSET
    #: Online protocol only (``packlab.sim.episode_results.OnlineOutcome``): packed
    #: volume / container volume when the episode ended, the box that fitted nowhere (None:
    #: every box was processed) and the boxes never processed. Absent from buffer records.
    space_utilization: float | UnsetType = UNSET
    stopped_at: RecordId | None | UnsetType = UNSET
    unprocessed: int | UnsetType = UNSET


class FinalPose(Struct, frozen=True):
    """A box's settled pose: centre (mm) and unit quaternion (w, x, y, z)."""

    position_mm: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


class Timing(Struct, frozen=True):
    """Where an episode's time went; which fields are present depends on how it ended."""

    episode_s: float | UnsetType = UNSET  # wall time of the episode (or until it was lost)
    cpu_s: float | UnsetType = UNSET  # its process's CPU time
    policy_s: float | UnsetType = UNSET  # in the policy's ``act`` (finished episodes)
    env_s: float | UnsetType = UNSET  # in the environment's steps (finished episodes)
    decisions: int | UnsetType = UNSET  # ``act`` calls (finished episodes)
    timeout_s: float | None | UnsetType = UNSET  # the limit passed (timed-out episodes)
    pid: int | UnsetType = UNSET  # the worker process


class _EpisodeHead(Struct, frozen=True, tag_field="status"):
    """Fields of every episode record; ``status`` ("ok" or "error") picks the kind."""

    format: str  # RUN_FORMAT
    case_id: str
    seed: int
    policy: str  # the registry name the episode ran under
    backend: str  # the transition backend
    difficulty: str
    n_objects: int

    @property
    def key(self) -> tuple[str, int, str, str]:
        """The record's identity: rerunning the same key is redoing work."""
        return (self.case_id, self.seed, self.policy, self.backend)


class EpisodeOk(_EpisodeHead, frozen=True, tag="ok"):
    """A finished episode: its scores, steps and final poses."""

    status: ClassVar[str] = "ok"
    metrics: MetricsRecord
    policy_time_s: float
    steps: tuple[StepRecord, ...]
    final_poses: dict[str, FinalPose | None]  # by str(internal_id); None: never placed
    timing: Timing
    #: Not played: copied from the episode of this run seed, whose policy plays the same
    #: episode for every seed (``packlab.bench.reuse``). The copy holds what playing it would
    #: have written (this seed's shown order, and the shown indices its actions name in it)
    #: except the times, which are the played episode's. An added key (the version stays
    #: run-2); absent from played episodes.
    reused_from_seed: int | UnsetType = UNSET


class EpisodeError(_EpisodeHead, frozen=True, tag="error"):
    """A failed episode: how (``error_kind``) and why (one line, and the traceback)."""

    status: ClassVar[str] = "error"
    error_kind: ErrorKind
    error: str
    traceback: str
    timing: Timing


#: One line of episodes.jsonl.
EpisodeRecord = EpisodeOk | EpisodeError


# -- the run summary (summary.json) -----------------------------------------------------------


class Cell(Struct, frozen=True):
    """One table cell: mean over seeds and sample std across seeds (None: nothing finished)."""

    mean: float | None
    std: float | None
    per_seed: dict[str, float]  # by str(seed)


class MetricCells(Struct, frozen=True):
    """The three metrics of one (method, group) of the table, and the space utilization
    where it is known (absent from older summaries)."""

    success_ratio: Cell
    compactness: Cell
    overall: Cell
    space_utilization: Cell | UnsetType = UNSET

    def cell(self, metric: str) -> Cell:
        """The cell of a metric by name (one of packlab.metrics.METRICS)."""
        value = getattr(self, metric)
        assert isinstance(value, Cell), metric
        return value


class CaseCells(Struct, frozen=True):
    """One case of one method: its difficulty and its three metrics over seeds."""

    difficulty: str
    success_ratio: Cell
    compactness: Cell
    overall: Cell
    space_utilization: Cell | UnsetType = UNSET  # as in MetricCells


class DecisionTimes(Struct, frozen=True):
    """How long a method's decisions took in one group of cases (a level, or ``all``), from the
    steps' ``decision_s`` / ``decision_cpu_s`` (``packlab.bench.decision_times``)."""

    decisions: int
    mean_ms: float
    p95_ms: float  # 95th percentile, linear interpolation between order statistics
    max_ms: float
    cpu_mean_ms: float
    cpu_max_ms: float
    #: Where the slowest decision was made: ``case_id``, run seed and step index.
    worst_case_id: str
    worst_seed: int
    worst_step: int


class AnswerFormats(Struct, frozen=True):
    """How a method's text answers were read, in steps (from ``StepRecord.format_event``,
    ``reasked`` and ``forced``): the answer was the JSON action, held it among other text, or
    held none; steps asked a second time; steps a forced set-aside replaced."""

    strict_json: int
    extra_text: int
    parse_fail: int
    reasked: int
    forced: int


class PolicyCounts(Struct, frozen=True):
    """A method's counters in a run (``packlab.bench.summary`` says what each counts)."""

    episodes: int
    errors: int
    steps: int
    invalid_steps: int
    set_aside: int
    unsettled_steps: int
    not_at_rest: int | None  # None: a migrated summary from before the count existed
    max_residual_linear_mps: float | None  # None: as not_at_rest
    max_residual_angular_radps: float | None
    decision_ms: float | None  # None: no decisions
    step_ms: float | None
    episode_s: float | None  # None: no finished episode
    #: Perceived runs only (absent otherwise): re-plan events per episode, and the
    #: mean perception errors over every shown object of every step (dims mm, yaw degrees)
    #: and over every step (heightmap mean absolute error, mm).
    replans_per_episode: float | UnsetType = UNSET
    missed_per_episode: float | UnsetType = UNSET
    looked_again_per_episode: float | UnsetType = UNSET
    dims_error_mm: float | None | UnsetType = UNSET
    yaw_error_deg: float | None | UnsetType = UNSET
    heightmap_mae_mm: float | None | UnsetType = UNSET
    #: Methods that read a model's text answer (steps carrying ``format_event``) only: how
    #: their answers were read. Absent for other methods and summaries made before the count.
    answer_formats: AnswerFormats | UnsetType = UNSET
    #: Per-decision time by level and over ``all`` levels; absent when no record of the method
    #: has per-step decision times (records written before steps were timed).
    decision_times: dict[str, DecisionTimes] | UnsetType = UNSET
    #: Noisy-execution runs only: the place skill's counts per episode, by kind (what
    #: it had to do to recover and how; ``packlab.sim.physics.place_skill.SkillReport``), and
    #: its placements per episode under ``placements``. Absent for other runs and runs written
    #: before the counts existed.
    skill_per_episode: dict[str, float] | UnsetType = UNSET
    #: Episodes of ``episodes`` copied from another seed's, not played (``EpisodeOk
    #: .reused_from_seed``); absent when none was.
    reused_episodes: int | UnsetType = UNSET


class ErrorEntry(Struct, frozen=True):
    """A failed episode in the summary; ``run`` is the run's label in a comparison."""

    case_id: str
    seed: int
    policy: str
    error: str
    run: str | UnsetType = UNSET


class SensingModes(Struct, frozen=True):
    """A run's observation and execution modes (config.json ``sensing``; ``bench.config``)."""

    observation: str  # core.choices.ObservationMode
    execution: str  # core.choices.ExecutionMode
    noise: str  # core.choices.NoisePreset
    segmentation: str | UnsetType = UNSET  # core.choices.Segmentation, perceived runs
    sides: str | UnsetType = UNSET  # core.choices.SideNames, when not the catalogue's
    size_prior: str | UnsetType = UNSET  # bench.options.SizePrior, perceived runs (absent: grid)


class RunSummary(Struct, frozen=True, kw_only=True):
    """summary.json: a run's numbers (``packlab.bench.summary.summarize``).

    ``table[method][group]`` holds the groups (difficulties, then "average"), ``per_case[method]
    [case_id]`` each case, ``counts[method]`` the counters. The run fields (suite ...
    cases_sha256) are those of config.json; absent when the summary was made without one.
    """

    format: str  # SUMMARY_FORMAT
    suite: str | None | UnsetType = UNSET
    backend: str | None | UnsetType = UNSET
    n_cases: int | None | UnsetType = UNSET
    cases_sha256: str | None | UnsetType = UNSET
    policies: tuple[str, ...]
    seeds: tuple[int, ...]
    difficulties: tuple[str, ...]
    metrics: tuple[str, ...] = ("success_ratio", "compactness", "overall")
    aggregation: str = ""
    table: dict[str, dict[str, MetricCells]]
    per_case: dict[str, dict[str, CaseCells]] = {}
    counts: dict[str, PolicyCounts]
    errors: tuple[ErrorEntry, ...] = ()
    #: The run's observation / execution / noise (config.json ``sensing``); absent
    #: when both modes are exact.
    sensing: SensingModes | None | UnsetType = UNSET
    #: The run's protocol (``buffer`` or ``online``) and, online, its lookahead;
    #: absent in summaries of runs made before the choice (they read as ``buffer``).
    protocol: str | UnsetType = UNSET
    lookahead: int | UnsetType = UNSET
    #: The run's ``--policy-arg`` options by policy (config.json ``policy_args``), so a row can
    #: be labelled with the prompt protocol and ablation options it ran with
    #: (``packlab.viz.labels.policy_label``); absent when the run gave none, and in summaries
    #: made before the key.
    policy_args: dict[str, JsonObject] | UnsetType = UNSET


class RunConfigHead(Struct, frozen=True, kw_only=True):
    """What a report reads of a run's config.json (the rest is ignored here)."""

    format: str  # one of RUN_FORMATS
    suite: str | None = None
    backend: str | None = None
    n_cases: int | None = None
    cases_sha256: str | None = None
    policies: tuple[str, ...]
    seeds: tuple[int, ...]
    difficulties: tuple[str, ...]
    sensing: SensingModes | None = None
    protocol: str | None = None  # absent: buffer
    lookahead: int | None = None  # online runs only
    policy_args: dict[str, JsonObject] | None = None  # --policy-arg options by policy


# -- the dataset info (PackData meta/info.json) -----------------------------------------------


class GeneratorInfo(Struct, frozen=True):
    name: str
    version: str
    seed_domain: str


class DifficultyCounts(Struct, frozen=True):
    """What one difficulty of a dataset holds and what it took to make."""

    requested: int
    episodes: int
    steps: int
    attempts: int
    rejected: int
    acceptance_rate: float | None  # None: nothing attempted
    rejections: dict[str, int]  # by reason
    failed_slots: tuple[int, ...]  # slots with no accepted case within the attempts


class DatasetCounts(Struct, frozen=True):
    episodes: int
    steps: int
    shards: int
    by_difficulty: dict[str, DifficultyCounts]


class ImageInfo(Struct, frozen=True):
    size: int
    format: str
    mode: str
    axes: str
    colour: str


class FilesInfo(Struct, frozen=True):
    steps: str
    episodes: str
    sft: str | None  # None: no SFT export
    sft_mode: str
    images: str


class DatasetInfo(Struct, frozen=True, kw_only=True):
    """meta/info.json: what a PackData directory holds and how it was made."""

    format_version: str  # PACKDATA_FORMAT
    name: str
    generator: GeneratorInfo
    generator_config: JsonObject  # packlab.datagen.config.DatasetConfig.to_dict()
    validation_backend: str
    prompt_version: str
    counts: DatasetCounts
    rejections: dict[str, int]
    image: ImageInfo
    files: FilesInfo


# -- decoding, with errors that name file, line, field and value ------------------------------

R = TypeVar("R")


class NotJSON(ValueError):
    """The bytes are not JSON at all (episodes.jsonl tells a torn last line by this)."""


class _Absent:
    def __repr__(self) -> str:
        return "<absent>"


ABSENT: object = _Absent()
_UNRESOLVED = object()
_PATH_PART = re.compile(r"\.([^.\[]+)|\[(\d+|\.\.\.)\]")
_MISSING_FIELD = re.compile(r"Object missing required field `([^`]+)`")


def _lookup(obj: object, path: str) -> object:
    """The value at a msgspec error path (``$.steps[3].action.x``); ABSENT where there is none,
    _UNRESOLVED where the path does not say (``[...]`` stands for some key of a dict)."""
    current = obj
    for name, index in _PATH_PART.findall(path):
        if index == "...":
            return _UNRESOLVED
        try:
            current = current[int(index)] if index else current[name]  # type: ignore[index]
        except (KeyError, IndexError, TypeError):
            return ABSENT
    return current


def field_error(
    exc: msgspec.ValidationError, obj: object, source: str, line: int | None
) -> RecordFormatError:
    """A msgspec validation error as a RecordFormatError: file, line, field path and value."""
    problem, _, at = str(exc).partition(" - at `")
    path = at.rstrip("`") if at else "$"
    missing = _MISSING_FIELD.fullmatch(problem)
    if missing:
        path = f"{path}.{missing.group(1)}"
        problem = "missing (a required field)"
    field = path[2:] if path.startswith("$.") else path.lstrip("$") or "<record>"
    value = _lookup(obj, path[1:])
    return RecordFormatError(
        source, line, field, value, problem, show_value=value is not _UNRESOLVED
    )


def loads(data: bytes | str, source: str, line: int | None = None) -> object:
    """Plain JSON (Python's parser, which also takes NaN); NotJSON when it is not JSON."""
    try:
        return json.loads(data)
    except ValueError as exc:
        where = f"{source}:{line}" if line is not None else source
        raise NotJSON(f"{where}: not JSON ({exc})") from None


#: The record types msgspec has built its type information for in this process.
_CONVERTED: set[type] = set()
_FIRST_CONVERSION = threading.Lock()


def convert(obj: object, kind: type[R], source: str, line: int | None = None) -> R:
    """Validate parsed JSON as ``kind``; RecordFormatError names what is wrong."""
    try:
        if kind in _CONVERTED:
            return msgspec.convert(obj, kind)
        # msgspec builds a type's information on its first conversion, and two threads doing
        # that at once (episodes finishing together under ``bench --concurrency``) crashed the
        # process with SIGSEGV; later conversions only read it and need no lock.
        with _FIRST_CONVERSION:
            value = msgspec.convert(obj, kind)
            _CONVERTED.add(kind)
            return value
    except msgspec.ValidationError as exc:
        raise field_error(exc, obj, source, line) from None


def _object(obj: object, source: str, line: int | None) -> dict[str, object]:
    if not isinstance(obj, dict):
        raise RecordFormatError(source, line, "<record>", obj, "expected a JSON object")
    return obj


def check_version(
    obj: dict[str, object], field: str, known: tuple[str, ...], source: str, line: int | None = None
) -> str | None:
    """The record's version (None when the field is absent); RecordFormatError when unknown."""
    if field not in obj:
        return None
    version = obj[field]
    if version not in known:
        raise RecordFormatError(
            source,
            line,
            field,
            version,
            f"unknown format version; this packlab reads {', '.join(known)} (a newer packlab "
            "wrote it? update packlab to read it)",
        )
    return str(version)


# -- migrations --------------------------------------------------------------------------------


def migrate_episode(obj: dict[str, object]) -> dict[str, object]:
    """An episode record written before records carried ``format`` (run-1, early run-2), in the
    current layout. Every change is a rename or a default, so no number changes:

    * ``status`` absent: "ok";
    * error records: ``error_kind`` absent (run-1) reads "exception", the only failure run-1
      recorded; ``traceback`` absent reads "";
    * ``metrics``: ``capped_placements`` (run-1) is ``unsettled_steps``; ``final_settle_steps``
      absent reads 0, ``at_rest`` True, ``residual_linear_mps`` / ``residual_angular_radps`` 0.0
      (run-1 did not measure them; docs/robustness.md);
    * ``steps[]``: ``capped`` (run-1) is ``not settled``; the speeds absent read 0.0.
    """
    out = {**obj, "format": RUN_FORMAT}
    out.setdefault("status", "ok")
    if out["status"] == "error":
        out.setdefault("error_kind", "exception")
        out.setdefault("traceback", "")
        out.setdefault("timing", {})
        return out
    metrics = out.get("metrics")
    if isinstance(metrics, dict):
        m = dict(metrics)
        capped = m.pop("capped_placements", 0)
        m.setdefault("unsettled_steps", capped)
        for name, default in (
            ("final_settle_steps", 0),
            ("at_rest", True),
            ("residual_linear_mps", 0.0),
            ("residual_angular_radps", 0.0),
        ):
            m.setdefault(name, default)
        out["metrics"] = m
    steps = out.get("steps")
    if isinstance(steps, list):
        out["steps"] = [_migrate_step(s) if isinstance(s, dict) else s for s in steps]
    return out


def _migrate_step(step: dict[str, object]) -> dict[str, object]:
    s = dict(step)
    capped = s.pop("capped", False)
    s.setdefault("settled", not capped)
    s.setdefault("max_linear_speed_mps", 0.0)
    s.setdefault("max_angular_speed_radps", 0.0)
    return s


def migrate_summary(obj: dict[str, object]) -> dict[str, object]:
    """A summary.json written before summaries carried ``format``, in the current layout:
    ``counts[method].capped_placements`` (run-1) is ``unsettled_steps``; ``not_at_rest`` and the
    largest residual speeds, absent before run-2, read None (unknown; the table shows "-")."""
    out = {**obj, "format": SUMMARY_FORMAT}
    counts = out.get("counts")
    if isinstance(counts, dict):
        migrated = {}
        for name, c in counts.items():
            if isinstance(c, dict):
                c = dict(c)
                capped = c.pop("capped_placements", 0)
                c.setdefault("unsettled_steps", capped)
                for key in ("not_at_rest", "max_residual_linear_mps", "max_residual_angular_radps"):
                    c.setdefault(key, None)
            migrated[name] = c
        out["counts"] = migrated
    return out


# -- readers -----------------------------------------------------------------------------------


def decode_episode(raw: bytes, source: str, line: int | None = None) -> EpisodeRecord:
    """One episodes.jsonl line as a typed record, its version checked (migrated when older).

    NotJSON when the line is not JSON (a torn write); RecordFormatError for an unknown version
    or a field missing or of the wrong type.
    """
    try:
        # msgspec types a decode to a union (not a type[T]) as Any.
        record: EpisodeRecord = msgspec.json.decode(raw, type=EpisodeRecord)
    except msgspec.DecodeError:  # not the current layout (or not JSON): the slow, careful path
        return episode_from_json(loads(raw, source, line), source, line)
    if record.format != RUN_FORMAT:
        check_version({"format": record.format}, "format", (RUN_FORMAT,), source, line)
    return record


def episode_from_json(obj: object, source: str, line: int | None = None) -> EpisodeRecord:
    """Parsed JSON of one episode record as a typed record (version checked, older migrated)."""
    record = _object(obj, source, line)
    if check_version(record, "format", (RUN_FORMAT,), source, line) is None:
        record = migrate_episode(record)
    return convert(record, EpisodeRecord, source, line)  # type: ignore[arg-type]


def summary_from_json(data: bytes | str, source: str) -> RunSummary:
    """summary.json as a RunSummary (version checked, older migrated)."""
    obj = _object(loads(data, source), source, None)
    if check_version(obj, "format", (SUMMARY_FORMAT,), source) is None:
        obj = migrate_summary(obj)
    return convert(obj, RunSummary, source)


def run_config_from_json(data: bytes | str, source: str) -> RunConfigHead:
    """The part of config.json a report needs; its ``format`` must be one of RUN_FORMATS."""
    obj = _object(loads(data, source), source, None)
    if check_version(obj, "format", RUN_FORMATS, source) is None:
        raise RecordFormatError(
            source,
            None,
            "format",
            ABSENT,
            f"no format version; not a packlab bench run directory's config "
            f"(expected one of {', '.join(RUN_FORMATS)})",
        )
    return convert(obj, RunConfigHead, source)


def dataset_info_from_json(data: bytes | str, source: str) -> DatasetInfo:
    """meta/info.json as a DatasetInfo; its ``format_version`` must be one of PACKDATA_FORMATS."""
    obj = _object(loads(data, source), source, None)
    if check_version(obj, "format_version", PACKDATA_FORMATS, source) is None:
        raise RecordFormatError(
            source,
            None,
            "format_version",
            ABSENT,
            f"no format version; not a PackData info file (expected {PACKDATA_FORMAT})",
        )
    return convert(obj, DatasetInfo, source)


# -- writers -----------------------------------------------------------------------------------


def to_builtins(record: Struct) -> dict[str, object]:
    """A record as plain JSON-able Python (field order kept; absent optional fields left out)."""
    out = msgspec.to_builtins(record)
    assert isinstance(out, dict)
    return out


def dumps_line(record: Struct) -> str:
    """One compact JSON line (no spaces: records are many and read by machines)."""
    return json.dumps(to_builtins(record), separators=(",", ":"))


__all__ = [
    "ABSENT",
    "FORMAT_EVENTS",
    "PACKDATA_FORMAT",
    "RUN_FORMAT",
    "RUN_FORMATS",
    "RUN_FORMAT_1",
    "SUMMARY_FORMAT",
    "ActionRecord",
    "AnswerFormats",
    "CaseCells",
    "Cell",
    "DatasetCounts",
    "DatasetInfo",
    "DecisionTimes",
    "DifficultyCounts",
    "EpisodeError",
    "EpisodeOk",
    "EpisodeRecord",
    "ErrorEntry",
    "FilesInfo",
    "FinalPose",
    "FormatEvent",
    "GeneratorInfo",
    "ImageInfo",
    "JsonObject",
    "JsonScalar",
    "JsonValue",
    "MetricCells",
    "MetricsRecord",
    "NotJSON",
    "PerceptionErrors",
    "PolicyCounts",
    "PoseEntry",
    "RecordFormatError",
    "RunConfigHead",
    "RunSummary",
    "SensingModes",
    "StepRecord",
    "Timing",
    "check_version",
    "convert",
    "dataset_info_from_json",
    "decode_episode",
    "dumps_line",
    "episode_from_json",
    "field_error",
    "loads",
    "migrate_episode",
    "migrate_summary",
    "run_config_from_json",
    "summary_from_json",
    "to_builtins",
]
