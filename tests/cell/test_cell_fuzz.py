"""Random mutations of valid requests (seeded, a few hundred) never get a 5xx, and the server
serves a valid request after them all."""

from __future__ import annotations

import copy
import json
import random

from cell_scenes import BUFFER_SESSION, BUFFER_STEP, PINHOLE_SESSION, SESSION, STEP

#: Values a mutation puts in place of a field: wrong types, extremes, empties, near misses.
ODD_VALUES = [
    None,
    True,
    0,
    -1,
    1,
    2**70,
    -(2**70),
    1e308,
    -1e308,
    1e-320,
    0.5,
    "",
    "x",
    "x" * 5000,
    "AAAA",
    "plan-fast",
    [],
    {},
    [0],
    [1, 2],
    [1, 2, 3],
    [1, 2, 3, 4],
    [[1, 0], [0, 1]],
    {"a": 1},
    [None, None, None],
    [600, 400, 400],
    [100000, 100000, 1],
    "pinhole",
    "orthographic",
    "png16",
    "u16",
]
SEEDS = 300


def _paths(node, prefix=()):
    """Every (path) to a dict key or list item in ``node``."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield (*prefix, key)
            yield from _paths(value, (*prefix, key))
    elif isinstance(node, list) and len(node) <= 8:  # not into long lists (none here)
        for i, value in enumerate(node):
            yield (*prefix, i)
            yield from _paths(value, (*prefix, i))


def _parent(node, path):
    for key in path[:-1]:
        node = node[key]
    return node


def mutate(request: dict, rng: random.Random) -> dict:
    """``request`` with one to three random mutations."""
    out = copy.deepcopy(request)
    for _ in range(rng.randint(1, 3)):
        paths = list(_paths(out))
        if not paths:
            break
        path = rng.choice(paths)
        parent, key = _parent(out, path), path[-1]
        kind = rng.random()
        if kind < 0.2 and isinstance(parent, dict):
            del parent[key]
        elif kind < 0.3 and isinstance(parent, dict):
            parent[f"extra_{rng.randint(0, 9)}"] = rng.choice(ODD_VALUES)
        elif kind < 0.45 and isinstance(parent[key], (int, float)) and parent[key] is not True:
            parent[key] = parent[key] * rng.choice([-1, 0, 2, 1000, 1e-6]) + rng.choice([0, 1])
        elif kind < 0.55 and isinstance(parent[key], str) and len(parent[key]) > 8:
            text = parent[key]  # image data: cut, or a character changed
            cut = rng.randrange(len(text))
            parent[key] = text[:cut] if rng.random() < 0.5 else text[:cut] + "!" + text[cut + 1 :]
        elif kind < 0.6 and isinstance(parent[key], list) and parent[key]:
            parent[key] = parent[key] + parent[key][:1]
        else:
            parent[key] = copy.deepcopy(rng.choice(ODD_VALUES))
    return out


def test_mutated_requests_never_get_a_5xx(http):
    rng = random.Random(20240)
    session_id = http.post("/v1/sessions", json=BUFFER_SESSION).json()["session_id"]
    statuses: dict[int, int] = {}
    for _ in range(SEEDS):
        target = rng.random()
        if target < 0.3:
            base = rng.choice([SESSION, BUFFER_SESSION, PINHOLE_SESSION])
            url, body = "/v1/sessions", mutate(base, rng)
        elif target < 0.7:
            url, body = (
                f"/v1/sessions/{session_id}/step",
                mutate(rng.choice([STEP, BUFFER_STEP]), rng),
            )
        else:
            bases = [
                {**SESSION, **STEP},
                {**BUFFER_SESSION, **BUFFER_STEP},
                {**PINHOLE_SESSION, **STEP},
            ]
            base = rng.choice(bases)
            url, body = "/v1/plan", mutate(base, rng)
        response = http.post(
            url, content=json.dumps(body), headers={"content-type": "application/json"}
        )
        statuses[response.status_code] = statuses.get(response.status_code, 0) + 1
        assert response.status_code < 500, (url, json.dumps(body)[:2000], response.text)
        if response.status_code >= 400:
            line = response.json()["error"]
            assert line and "\n" not in line
    assert statuses.get(422, 0) > SEEDS / 4 and statuses.get(200, 0) + statuses.get(201, 0) > 10
    assert http.get("/v1/health").json()["status"] == "ok"
    assert http.post(f"/v1/sessions/{session_id}/step", json=BUFFER_STEP).status_code == 200
