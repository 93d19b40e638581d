"""Labelled states from closed-loop rollouts on generated cases (DAgger's data step).

Each case is played once in the geometric backend (fast, exact Eq. 2) by an *actor*: the
teacher itself (round 0: the teacher's own trajectories) or the current student (rounds >= 1:
the states the student reaches, which the teacher's trajectories never show). At every step the
proposer lists its K placements and the teacher labels the state with its pick among them (the
``plan`` teacher adds its own pick when the K missed it, and a soft target), so
the data is always "what the teacher would do here", wherever "here" came from. Steps where
nothing fits are not recorded (the policy falls back to SDF-Pack there).

``RobotPath`` collects on the robot path instead: MuJoCo, perceived observations and
noisy execution under a sensor preset. The teacher then labels what the robot is shown (perceived
sizes, a noisy heightmap), so a student trained on those rows learns to act on what a robot cell
sees, and the states follow from placements that landed off plan.

Cases run in worker processes; each finished case's states are appended to the file at once, so
a crash loses at most the cases in flight, and a rerun skips the cases already in the file.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from packlab.cases.fingerprint import case_fingerprint
from packlab.core.choices import NoisePreset
from packlab.core.feasibility import observation_candidates
from packlab.core.types import Action, Case, Observation, Unparsable
from packlab.policies.candidates import ProposerConfig, propose_from
from packlab.policies.listed import ListedTeacher
from packlab.policies.registry import make_policy
from packlab.sim.episode import policy_start, run_episode
from packlab.sim.modes import DEFAULT_NOISE, EpisodeModes, episode_modes
from packlab.vlm.candidate.states import LabelledState, append_states, make_state, read_states

#: (policy name, options) of the actor; ``None`` follows the teacher.
ActorSpec = tuple[str, dict[str, Any]] | None
DEFAULT_PROPOSER = ProposerConfig()


@dataclass(frozen=True, slots=True)
class RobotPath:
    """Collect on the honest robot path: perceived + noisy under ``noise``, on MuJoCo."""

    noise: NoisePreset = DEFAULT_NOISE

    def modes(self) -> EpisodeModes:
        return episode_modes("perceived", "noisy", self.noise)


@dataclass
class Labeller:
    """A policy that records every state it sees, labelled by the teacher, while acting as the
    actor (or the teacher when there is none)."""

    teacher: ListedTeacher
    proposer: ProposerConfig
    source: str
    actor: Any = None
    name: str = "labeller"
    states: list[LabelledState] = field(default_factory=list)

    #: Its rows name their case (and the oracle teacher replays its plan); the actor it plays
    #: is handed only what the episode hands any policy.
    needs_case = True

    def reset(self, case: Case, seed: int) -> None:
        self._case = case
        self._case_sha256 = case_fingerprint(case)  # every row names its case by content too
        self.teacher.reset(case, seed)
        self._fallback = make_policy("sdf")
        self._fallback.reset(policy_start(self._fallback, case, seed), seed)
        if self.actor is not None:
            self.actor.reset(policy_start(self.actor, case, seed), seed)
        self.states = []

    def act(self, observation: Observation) -> Action | Unparsable:
        cands = observation_candidates(observation)
        listed = propose_from(cands, self.proposer)
        if not listed:  # nothing fits: any action ends the episode the same way
            return self._fallback.act(observation)
        told = self.teacher.label(observation, cands, listed)
        case, teacher = self._case, self.teacher.teacher
        state = make_state(
            case.episode_id, case.difficulty, observation, told.listed, teacher, told.label,
            self.source, told.soft, told.added, self._case_sha256,
        )  # fmt: skip
        self.states.append(state)
        if self.actor is not None:
            return self.actor.act(observation)
        return told.action


@dataclass(frozen=True)
class _Job:
    case: Case
    teacher: str
    proposer: ProposerConfig
    source: str
    actor: ActorSpec
    robot: RobotPath | None = None


def _play(job: _Job) -> tuple[str, list[LabelledState], float]:
    actor = make_policy(job.actor[0], **job.actor[1]) if job.actor is not None else None
    labeller = Labeller(ListedTeacher(job.teacher), job.proposer, job.source, actor)
    if job.robot is None:  # exact: the geometric backend is exact Eq. 2 and fast
        result = run_episode(job.case, labeller, seed=0, backend="geometric")
        return job.case.episode_id, labeller.states, result.metrics.overall
    modes = job.robot.modes()
    result = run_episode(
        job.case, labeller, seed=0, backend="mujoco", perceiver=modes.perceiver,
        execution=modes.execution, sides=modes.sides,
    )  # fmt: skip
    return job.case.episode_id, labeller.states, result.metrics.overall


def done_cases(path: Path) -> set[str]:
    return {s.case_id for s in read_states(path)} if path.is_file() else set()


def collect(
    cases: Sequence[Case],
    out: Path,
    teacher: str,
    source: str,
    actor: ActorSpec = None,
    proposer: ProposerConfig = DEFAULT_PROPOSER,
    workers: int = 2,
    progress: bool = True,
    on_case: Callable[[str, float], None] | None = None,
    robot: RobotPath | None = None,
) -> int:
    """Play every case not yet in ``out`` and append its labelled states; the number appended.
    ``on_case(case_id, overall)`` sees each finished case (the actor's closed-loop score);
    ``robot`` plays on the honest robot path instead of exact observations."""
    ListedTeacher(teacher)  # refuse an unknown teacher before starting workers
    done = done_cases(out)
    jobs = [
        _Job(c, teacher, proposer, source, actor, robot) for c in cases if c.episode_id not in done
    ]
    return play_and_append(_play, jobs, out, f"collect {source}", workers, progress, on_case)


def play_and_append(
    play: Callable[[Any], tuple[str, list[LabelledState], float]],
    jobs: Sequence[Any],
    out: Path,
    desc: str,
    workers: int,
    progress: bool,
    on_case: Callable[[str, float], None] | None = None,
) -> int:
    """Run ``play`` on every job in worker processes and append each finished case's states to
    ``out`` at once (a crash loses only the cases in flight); the number of states appended.
    ``play`` returns (case id, states, the actor's Overall) and must be picklable."""
    out.parent.mkdir(parents=True, exist_ok=True)
    written = 0
    bar = tqdm(total=len(jobs), desc=desc, unit="case", disable=not progress)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for case_id, states, overall in pool.map(play, jobs, chunksize=1):
            written += append_states(out, states)
            if on_case is not None:
                on_case(case_id, overall)
            bar.update(1)
    bar.close()
    return written
