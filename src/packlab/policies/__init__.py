"""Packing policies: the Policy protocol, the registry and the built-ins."""

from packlab.core.protocols import EpisodeStart, Policy
from packlab.policies.registry import available_policies, make_policy, register_policy

__all__ = ["EpisodeStart", "Policy", "available_policies", "make_policy", "register_policy"]
