"""Guillotine assembly: fill a cuboid with every given box, merging boxes that share a face (pure).

A *guillotine* packing is one that a sequence of straight cuts through whole pieces can make:
the container is cut in two, each part is cut in two, and so on. Zhao et al.'s CUT sets and
packlab's ``cut`` family are made exactly so (``datagen/cut_family.py``). Read backwards, every
cut is a *merge*: two pieces that share a whole face (the same footprint, stacked; or the same
height and one footprint side, side by side) join into one cuboid. So the boxes fill the
container in a guillotine packing iff merges can turn them into one piece of the container's
size.

That search needs no positions at all: a piece's insides do not matter to what it can merge
with, only its size. A state is the multiset of piece sizes (footprint sides sorted, since a
piece may turn by 90 degrees about z like any box; height in mm), so states are small, many
orders of the same merges meet in one state (a memo of hopeless states), and a node costs about
0.1 ms for 30 boxes, against several for the skyline search (:mod:`.skyline`), which places
boxes one by one on a heightmap and often wanders for thousands of nodes in a wrong first floor.
Measured on 124 generated hard ``cut`` training cases of 19-32 boxes (four training seeds, both
arrival orders), from an empty container with every box known: the skyline search found 29 of
the first 40 within 20 000 nodes; this search finds 123 of the 124 within 50 000 nodes (most in
as many nodes as boxes).

Branch order (decides which packing is found first, not whether one exists): merges of a piece
with few possible partners first (a piece that can join only one other piece is probably its
sibling), then merges whose result spans a side of the container, then larger results.

Restarts: one wrong merge early on is not undone within any budget (the merges of the other
pieces below it multiply), so the budget is spent on many short attempts of
``ATTEMPT_NODES`` nodes. The first follows the branch order; each later one adds to every
partner count a random amount in [0, ``PARTNER_NOISE``) from a generator seeded by the attempt
(deterministic). States proven hopeless stay proven across attempts. Chosen on those training
cases: attempts of 250 nodes doubling each time found 121 of the 124 and attempts of 300 nodes
with the noise 123 (noise 1: 122, 3: 123; attempts of 600 nodes: 123).

Second search, when the merges ran out of budget: **cuts, top down**. With few distinct sizes
(Zhao et al.'s own sets: a 10-unit cube, sides 2-5 units) many pieces share a face by
coincidence and wrong merges multiply; from an empty container the merges found 17 of 30 such
packings within 50 000 nodes. Cutting the container instead (an axis, a position, and which
sizes go to each side, by volume and fit) makes the two parts independent problems, each
memoised on (part size, multiset of sizes), so a wrong guess in one part costs nothing in the
other. Its nodes cost more (up to a few ms: the splits), so it gets ``cut_nodes`` (5 000) and
runs only after the merges' budget is spent: on those 30 it finds 4 more (21 of 30). The merges
stay first because on packlab's ``cut`` family they find nearly every packing in as many nodes
as boxes.

Not complete for packings that are not guillotine (a pinwheel of five boxes): both answer "not
found" for them and the caller falls back to :mod:`.skyline`.
"""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from packlab.policies.plan.skyline import Block, Placed, SkylineResult

#: A piece's size: footprint sides in cells (shorter first) and height in mm.
Size = tuple[int, int, int]


def piece_size(a: int, b: int, height_mm: int) -> Size:
    """The size of a piece whose footprint is ``a`` x ``b`` cells, shorter side first (a piece
    may turn about z, so ``a x b`` and ``b x a`` are one size)."""
    return (a, b, height_mm) if a <= b else (b, a, height_mm)


@dataclass(frozen=True, slots=True)
class _Leaf:
    block: Block

    @property
    def height_mm(self) -> int:
        return self.block.height_mm


@dataclass(frozen=True, slots=True)
class _Stack:
    """Two pieces of one footprint, ``top`` on ``bottom``."""

    bottom: _Piece
    top: _Piece
    height_mm: int


@dataclass(frozen=True, slots=True)
class _Side:
    """Two pieces of one height sharing a footprint side ``shared``; ``first`` is ``along``
    cells long across it, ``second`` follows."""

    first: _Piece
    second: _Piece
    shared: int
    along: int
    height_mm: int


_Piece = _Leaf | _Stack | _Side
#: A merge: the two sizes joined and the size they make.
_Merge = tuple[Size, Size, Size]


def _fits(size: Size, part: Size) -> bool:
    """Whether a piece fits in a part, turned or not (both sizes shorter side first, so the
    shorter sides and the longer sides compare)."""
    return size[0] <= part[0] and size[1] <= part[1] and size[2] <= part[2]


def _joins(p: Size, q: Size) -> list[Size]:
    """Every size that pieces of sizes ``p`` and ``q`` make when merged."""
    out = []
    if p[:2] == q[:2]:
        out.append(piece_size(p[0], p[1], p[2] + q[2]))
    if p[2] == q[2]:
        for s1, o1 in ((p[0], p[1]), (p[1], p[0])):
            for s2, o2 in ((q[0], q[1]), (q[1], q[0])):
                if s1 == s2:
                    out.append(piece_size(s1, o1 + o2, p[2]))
    return out


class _Search:
    def __init__(
        self,
        goal: Size,
        max_nodes: int,
        shuffle: random.Random | None,
        failed: set[tuple[tuple[Size, int], ...]],
    ) -> None:
        self.goal = goal
        self.max_nodes = max_nodes
        self.shuffle = shuffle
        self.failed = failed
        self.nodes = 0
        self.merges: list[_Merge] = []

    def exhausted(self) -> bool:
        return self.nodes >= self.max_nodes

    def _moves(self, state: Counter[Size]) -> list[_Merge]:
        sizes = sorted(state)
        moves: dict[_Merge, None] = {}
        partners: Counter[Size] = Counter()
        for i, p in enumerate(sizes):
            for q in sizes[i:]:
                if p == q and state[p] < 2:
                    continue
                for r in _joins(p, q):
                    if _fits(r, self.goal) and (p, q, r) not in moves:
                        moves[(p, q, r)] = None
                        partners[p] += 1
                        partners[q] += 1
        ga, gb, gh = self.goal

        def order(m: _Merge) -> tuple[float, ...]:
            p, q, r = m
            spans = (r[0] in (ga, gb)) + (r[1] in (ga, gb)) + (r[2] == gh)
            noise = self.shuffle.random() * PARTNER_NOISE if self.shuffle is not None else 0.0
            return (min(partners[p], partners[q]) + noise, -spans, -r[0] * r[1] * r[2])

        return sorted(moves, key=order)

    def solve(self, state: Counter[Size]) -> bool:
        if self.exhausted():
            return False
        if sum(state.values()) == 1:
            return next(iter(state)) == self.goal
        key = tuple(sorted(state.items()))
        if key in self.failed:
            return False
        self.nodes += 1
        for p, q, r in self._moves(state):
            for s in (p, q):
                state[s] -= 1
                if not state[s]:
                    del state[s]
            state[r] += 1
            self.merges.append((p, q, r))
            if self.solve(state):
                return True
            self.merges.pop()
            state[r] -= 1
            if not state[r]:
                del state[r]
            state[p] += 1
            state[q] += 1
            if self.exhausted():
                return False
        self.failed.add(key)
        return False


#: Nodes of one attempt, and the most a later attempt adds to a partner count (module
#: docstring: restarts).
ATTEMPT_NODES = 300
PARTNER_NOISE = 2.0


def guillotine_fill(
    blocks: Sequence[Block],
    footprint: tuple[int, int],
    height_mm: int,
    base_mm: int = 0,
    max_nodes: int = 50_000,
    cut_nodes: int = 5_000,
) -> SkylineResult:
    """Pack every block into the cuboid ``footprint`` (cells along x, y) x ``height_mm`` resting
    on a flat floor at ``base_mm`` (module docstring), or say that none was found within
    ``max_nodes`` merge nodes and then ``cut_nodes`` cut nodes. The placements come in a build
    order (by base height: in a packing with no gap every box then rests fully on boxes already
    placed)."""
    goal = piece_size(footprint[0], footprint[1], height_mm)
    volume = sum(b.length * b.width * b.height_mm for b in blocks)
    if not blocks or volume != goal[0] * goal[1] * goal[2]:
        return SkylineResult(None, 0, False)
    merges, nodes, exhausted = _merge_fill(blocks, goal, max_nodes)
    if merges is not None:
        root = _assemble(blocks, merges)
    elif exhausted and cut_nodes:
        cut = _CutSearch(cut_nodes)
        start = tuple(sorted(Counter(piece_size(*b.size) for b in blocks).items()))
        try:
            found = cut.solve(goal, start)
        except _OutOfBudget:
            found = False
        nodes += cut.nodes
        if not found:
            return SkylineResult(None, nodes, True)
        root = cut.tree(goal, start, _leaves(blocks))
    else:
        return SkylineResult(None, nodes, exhausted)
    placed = _place(root, 0, 0, base_mm, footprint[0], footprint[1])
    return SkylineResult(tuple(sorted(placed, key=_build_key)), nodes, False)


def _merge_fill(
    blocks: Sequence[Block], goal: Size, max_nodes: int
) -> tuple[list[_Merge] | None, int, bool]:
    """The merge search with its restarts (module docstring): (the merges of a packing or None,
    nodes spent, whether the budget ran out)."""
    start = Counter(piece_size(*b.size) for b in blocks)
    failed: set[tuple[tuple[Size, int], ...]] = set()
    spent, attempt = 0, 0
    while spent < max_nodes:
        budget = min(ATTEMPT_NODES, max_nodes - spent)
        shuffle = random.Random(attempt) if attempt else None
        search = _Search(goal, budget, shuffle, failed)
        found = search.solve(Counter(start))
        spent += search.nodes
        if found:
            return search.merges, spent, False
        if not search.exhausted():  # searched to the end: no guillotine packing
            return None, spent, False
        attempt += 1
    return None, spent, True


def _build_key(p: Placed) -> tuple[int, int, int]:
    return (p.z_mm, p.x, p.y)


def _leaves(blocks: Sequence[Block]) -> dict[Size, list[_Piece]]:
    pieces: dict[Size, list[_Piece]] = {}
    for b in blocks:
        pieces.setdefault(piece_size(*b.size), []).append(_Leaf(b))
    return pieces


def _assemble(blocks: Sequence[Block], merges: Sequence[_Merge]) -> _Piece:
    """Replay the merges on real pieces: the tree of the packing found."""
    pieces = _leaves(blocks)
    for p, q, r in merges:
        first, second = pieces[p].pop(), pieces[q].pop()
        pieces.setdefault(r, []).append(_merged(first, p, second, q, r))
    (root,) = [piece for group in pieces.values() for piece in group]
    return root


def _merged(first: _Piece, p: Size, second: _Piece, q: Size, r: Size) -> _Piece:
    if p[:2] == q[:2] and piece_size(p[0], p[1], p[2] + q[2]) == r:
        return _Stack(first, second, r[2])
    for s1, o1 in ((p[0], p[1]), (p[1], p[0])):
        for s2, o2 in ((q[0], q[1]), (q[1], q[0])):
            if s1 == s2 and piece_size(s1, o1 + o2, p[2]) == r:
                return _Side(first, second, s1, o1, p[2])
    raise AssertionError(f"no merge of {p} and {q} makes {r}")


def _place(piece: _Piece, x: int, y: int, z: int, fx: int, fy: int) -> list[Placed]:
    """The boxes of ``piece`` placed with its min corner at (x, y, z) and footprint fx x fy."""
    if isinstance(piece, _Leaf):
        b = piece.block
        rotation = 0 if (b.length, b.width) == (fx, fy) else 1
        return [Placed(b.key, rotation, x, y, z, fx, fy, b.height_mm)]
    if isinstance(piece, _Stack):
        return _place(piece.bottom, x, y, z, fx, fy) + _place(
            piece.top, x, y, z + piece.bottom.height_mm, fx, fy
        )
    s, a = piece.shared, piece.along
    if fx == s:  # the shared side lies along x: the two pieces follow each other along y
        return _place(piece.first, x, y, z, s, a) + _place(piece.second, x, y + a, z, s, fy - a)
    return _place(piece.first, x, y, z, a, s) + _place(piece.second, x + a, y, z, fx - a, s)


class _OutOfBudget(Exception):
    pass


#: A multiset of piece sizes as the cut search keys it: (size, count) pairs, sorted.
_Sizes = tuple[tuple[Size, int], ...]
#: How a part was cut: (axis, position, the first part's sizes, the second part's); axis 2 is
#: height, 0 and 1 the part's shorter and longer footprint side.
_Cut = tuple[int, int, _Sizes, _Sizes]


class _CutSearch:
    """Top-down guillotine search (module docstring): a part and a multiset of sizes of its
    volume are packable iff they are one piece of the part's size, or some cut splits them into
    two packable parts."""

    def __init__(self, max_nodes: int) -> None:
        self.max_nodes = max_nodes
        self.nodes = 0
        #: (part, sizes) -> how it was cut (None: a single piece), or False: not packable.
        self.memo: dict[tuple[Size, _Sizes], _Cut | None | bool] = {}

    def solve(self, part: Size, sizes: _Sizes) -> bool:
        key = (part, sizes)
        if key in self.memo:
            return self.memo[key] is not False
        self.nodes += 1
        if self.nodes > self.max_nodes:
            raise _OutOfBudget
        if len(sizes) == 1 and sizes[0][1] == 1:
            self.memo[key] = None if sizes[0][0] == part else False
            return self.memo[key] is None
        if not all(_fits(s, part) for s, _ in sizes):
            self.memo[key] = False
            return False
        for cut in self._cuts(part, sizes):
            axis, p, first, second = cut
            a, b = self._parts(part, axis, p)
            # the smaller part first: it is the cheaper one to refute
            if self.solve(a, first) and self.solve(b, second):
                self.memo[key] = cut
                return True
        self.memo[key] = False
        return False

    @staticmethod
    def _parts(part: Size, axis: int, p: int) -> tuple[Size, Size]:
        a, b, h = part
        if axis == 2:
            return (a, b, p), (a, b, h - p)
        if axis == 0:
            return piece_size(p, b, h), piece_size(a - p, b, h)
        return piece_size(a, p, h), piece_size(a, b - p, h)

    def _cuts(self, part: Size, sizes: _Sizes):
        """Every (axis, position, sizes of the first part, sizes of the second) whose first part
        is at most half the side (the other half is the mirror image)."""
        for axis in (2, 0, 1):
            if axis == 1 and part[0] == part[1]:
                continue  # a square part's two sides cut alike
            side = part[axis]
            # positions the pieces' extents along the axis can add up to, from both ends
            reach = 1
            for (a, b, h), n in sizes:
                for _ in range(n):
                    reach |= reach << h if axis == 2 else (reach << a) | (reach << b)
            for p in range(1, side // 2 + 1):
                if not (reach >> p) & 1 or not (reach >> (side - p)) & 1:
                    continue
                first, second = self._parts(part, axis, p)
                for split in self._splits(sizes, first, second):
                    yield (axis, p, *split)

    def _splits(self, sizes: _Sizes, first: Size, second: Size):
        """The ways to send each size's pieces to the two parts with the first part's volume,
        every piece fitting the part it goes to (larger pieces decided first)."""
        order = sorted(sizes, key=lambda sn: -sn[0][0] * sn[0][1] * sn[0][2])
        volumes = [s[0] * s[1] * s[2] for s, _ in order]
        fit1 = [_fits(s, first) for s, _ in order]
        fit2 = [_fits(s, second) for s, _ in order]
        if not all(f1 or f2 for f1, f2 in zip(fit1, fit2)):
            return
        target = first[0] * first[1] * first[2]
        rest = [0] * (len(order) + 1)
        for i in range(len(order) - 1, -1, -1):
            rest[i] = rest[i + 1] + volumes[i] * order[i][1]
        taken = [0] * len(order)

        def walk(i: int, volume: int):
            if volume == target:
                # every size not reached yet goes whole to the second part (taken[j] is 0 there)
                if all(fit2[j] for j in range(i, len(order))):
                    one = tuple(sorted((order[j][0], taken[j]) for j in range(i) if taken[j]))
                    two = tuple(
                        sorted(
                            (order[j][0], order[j][1] - taken[j])
                            for j in range(len(order))
                            if order[j][1] - (taken[j] if j < i else 0)
                        )
                    )
                    yield one, two
                return
            if i == len(order) or volume + rest[i] < target:
                return
            n = order[i][1]
            low = 0 if fit2[i] else n
            high = n if fit1[i] else 0
            for k in range(high, low - 1, -1):
                if volume + k * volumes[i] <= target:
                    taken[i] = k
                    yield from walk(i + 1, volume + k * volumes[i])
            taken[i] = 0

        yield from walk(0, 0)

    def tree(self, part: Size, sizes: _Sizes, pieces: dict[Size, list[_Piece]]) -> _Piece:
        """The packing found for (part, sizes), its leaves taken from ``pieces``."""
        cut = self.memo[(part, sizes)]
        if cut is None:
            return pieces[part].pop()
        assert isinstance(cut, tuple), "tree() of a part that was not solved"
        axis, p, first, second = cut
        a, b = self._parts(part, axis, p)
        one, two = self.tree(a, first, pieces), self.tree(b, second, pieces)
        if axis == 2:
            return _Stack(one, two, part[2])
        shared = part[1] if axis == 0 else part[0]
        return _Side(one, two, shared, p, part[2])
