"""How policies, groups and metrics are named in tables and figures (pure strings)."""

from __future__ import annotations

from packlab.metrics import AVERAGE

#: How methods are called in tables and figures (the paper's names); others print as registered.
DISPLAY_NAMES = {
    "dblf": "DBLF",
    "hm": "HM",
    "mta": "MTA",
    "ffp": "FFP",
    "sdf": "SDF-Pack",
    "plan": "Plan (completion + lookahead)",
    "plan-fast": "Plan (completion + lookahead, fast)",
    "plan-lookahead": "Plan (lookahead only)",
    "proposer": "Proposer (index 0)",
    "vlm-small": "PackLab pointer LM (vlm-small, candidate mode)",
    # The learned rows of the default table: the paper's names for its baselines (the agents are
    # IR-BPP- and TAP-Net-style, trained here; docs/rl.md) and the candidate-mode model, whatever
    # checkpoint `--policy-arg vlm:model=` names. Its row says what the shipped model is (issue
    # 36): a Qwen3-VL text stack with a pointer head that reads the heightmap as digits; its image
    # input never changed a decision (docs/vlm.md), so it ships without the vision tower.
    "vlm": "PackLab pointer LM",
    "irbpp": "IR-BPP",
    "tapnet": "TAP-Net",
    "random": "Random",
    "oracle": "Oracle (gt plan)",
}
METRIC_SHORT = {"success_ratio": "SR", "compactness": "Compact.", "overall": "Overall"}


def display_name(policy: str) -> str:
    return DISPLAY_NAMES.get(policy, policy)


def group_title(group: str) -> str:
    return "Average" if group == AVERAGE else (group.capitalize() if group else "Unlabelled")
