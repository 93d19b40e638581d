"""Scenario sampling: container, stack height, layer heights and object count of one case.

Pure: every draw comes from the generator passed in. The published parameters come from
``packlab.datagen.config``; this module only knows how to draw from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from packlab.core.types import Container
from packlab.datagen.config import CaseConfig, DifficultySpec


@dataclass(frozen=True, slots=True)
class Scenario:
    """The sampled frame of one case, before any layout is drawn."""

    container: Container
    stack_height_mm: int  # the perfect layout's top; a whole number of cm
    layer_heights_mm: tuple[int, ...]  # bottom to top, each in the object height range
    n_objects: int
    base_size_mm: tuple[int, int, int]  # the table entry the container was jittered from


def _clamp(v: int, lo: int, hi: int) -> int:
    return min(max(v, lo), hi)


def sample_container(
    spec: DifficultySpec, cfg: CaseConfig, rng: np.random.Generator
) -> tuple[Container, tuple[int, int, int]]:
    """A base size from the table, x/y jittered in whole grid cells and z in whole cm, clamped."""
    base = spec.base_sizes_mm[int(rng.integers(len(spec.base_sizes_mm)))]
    lim = cfg.container
    kxy = lim.jitter_xy_mm // cfg.cell_xy_mm
    kz = lim.jitter_z_mm // lim.jitter_z_step_mm
    x = base[0] + cfg.cell_xy_mm * int(rng.integers(-kxy, kxy + 1))
    y = base[1] + cfg.cell_xy_mm * int(rng.integers(-kxy, kxy + 1))
    z = base[2] + lim.jitter_z_step_mm * int(rng.integers(-kz, kz + 1))
    size = (_clamp(x, *lim.clamp_xy_mm), _clamp(y, *lim.clamp_xy_mm), _clamp(z, *lim.clamp_z_mm))
    return Container(size, cfg.cell_xy_mm, cfg.cell_z_mm), base


def stack_height_choices(
    container_z_mm: int, n_layers: int, spec: DifficultySpec, cfg: CaseConfig
) -> range:
    """Stack heights (mm, whole steps) within the ratio range that ``n_layers`` layers can fill."""
    step = cfg.objects.height_step_mm
    h_lo, h_hi = cfg.objects.layer_height_mm
    r_lo, r_hi = spec.height_ratio
    lo = max(math.ceil(r_lo * container_z_mm / step - 1e-9), math.ceil(n_layers * h_lo / step))
    hi = min(math.floor(r_hi * container_z_mm / step + 1e-9), n_layers * h_hi // step)
    return range(lo * step, hi * step + 1, step) if lo <= hi else range(0)


def split_height(
    total_mm: int, n_parts: int, lo_mm: int, hi_mm: int, step_mm: int, rng: np.random.Generator
) -> tuple[int, ...]:
    """``total_mm`` as ``n_parts`` heights in [lo, hi], each a whole number of steps.

    Each part starts at ``lo`` and the spare steps are handed out one by one to random parts
    with room left, which draws a random composition under the caps without rejection.
    """
    units = total_mm // step_mm
    lo_u, hi_u = lo_mm // step_mm, hi_mm // step_mm
    if total_mm % step_mm or not n_parts * lo_u <= units <= n_parts * hi_u:
        raise ValueError(
            f"cannot split {total_mm} mm into {n_parts} parts of [{lo_mm}, {hi_mm}] mm"
        )
    parts = np.full(n_parts, lo_u, dtype=np.int64)
    spare = units - n_parts * lo_u
    # Dirichlet weights make uneven splits as likely as even ones; the loop respects the caps.
    weights = rng.dirichlet(np.ones(n_parts))
    while spare:
        room = parts < hi_u
        p = weights * room
        take = rng.multinomial(spare, p / p.sum())
        take = np.minimum(take, hi_u - parts)
        parts += take
        spare -= int(take.sum())
    return tuple(int(p) * step_mm for p in parts)


def sample_scenario(spec: DifficultySpec, cfg: CaseConfig, rng: np.random.Generator) -> Scenario:
    """Container, layer count, stack height, layer heights and object count of one case."""
    container, base = sample_container(spec, cfg, rng)
    layer_options = list(range(spec.n_layers[0], spec.n_layers[1] + 1))
    n_layers = int(rng.choice(layer_options))
    heights = stack_height_choices(container.height_mm, n_layers, spec, cfg)
    if not heights:
        # Only reachable with custom specs: fall back to any layer count that fits this container.
        fitting = [
            n for n in layer_options if stack_height_choices(container.height_mm, n, spec, cfg)
        ]
        if not fitting:
            raise ValueError(f"no stack height fits container {container.size_mm} for {spec.name}")
        n_layers = int(rng.choice(fitting))
        heights = stack_height_choices(container.height_mm, n_layers, spec, cfg)
    stack = int(heights[int(rng.integers(len(heights)))])
    obj = cfg.objects
    layer_heights = split_height(stack, n_layers, *obj.layer_height_mm, obj.height_step_mm, rng)
    n_objects = int(rng.integers(spec.n_objects[0], spec.n_objects[1] + 1))
    return Scenario(container, stack, layer_heights, max(n_objects, n_layers), base)
