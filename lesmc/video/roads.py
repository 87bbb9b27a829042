"""The synthetic world's road network: curved roads, junctions, two-way lanes.

Roads are smooth curves across the world (``y = f(x)`` for east-west roads,
``x = g(y)`` for north-south ones); every crossing is a junction. The network
is a networkx graph whose edges carry the polyline between two junctions, which
is what vehicles drive along (in world pixels).
"""

from __future__ import annotations

import bisect
import itertools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import networkx as nx


@dataclass(frozen=True)
class Road:
    """One road: ``offset + amp * sin(2 pi t / wavelength + phase)`` across the world.

    ``horizontal`` roads give y as a function of x; vertical ones x as a function of y.
    """

    horizontal: bool
    offset: float
    amp: float
    wavelength: float
    phase: float

    def across(self, t: np.ndarray) -> np.ndarray:
        """The cross coordinate at along-coordinate ``t``."""
        return self.offset + self.amp * np.sin(2 * np.pi * t / self.wavelength + self.phase)

    def points(self, t: np.ndarray) -> np.ndarray:
        """World (x, y) points of the road at along-coordinates ``t``."""
        c = self.across(t)
        return np.stack([t, c] if self.horizontal else [c, t], axis=1)


@dataclass
class Edge:
    """A drivable road piece between two junctions: polyline and cumulative arc length."""

    points: np.ndarray
    arclen: np.ndarray
    length: float = field(init=False)  #: the total arc length, ``arclen[-1]``
    _knots: list[float] = field(init=False, repr=False)  #: ``arclen`` as Python floats

    def __post_init__(self) -> None:
        self.length = float(self.arclen[-1])
        self._knots = self.arclen.tolist()

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and unit tangent at arc length ``s`` (clamped to the edge): clamp,
        bisect the knots, interpolate, on Python floats (every vehicle asks once a frame
        and once a traffic substep; numpy's per-call cost dominated a single lookup)."""
        knots = self._knots
        s = min(max(float(s), 0.0), self.length)
        i = min(max(bisect.bisect_right(knots, s) - 1, 0), len(knots) - 2)
        seg = self.points[i + 1] - self.points[i]
        seg_len = max(knots[i + 1] - knots[i], 1e-9)
        return self.points[i] + seg * ((s - knots[i]) / seg_len), seg / seg_len


def make_roads(rng: np.random.Generator, size: tuple[int, int], spacing: float) -> list[Road]:
    """Roads over a ``(width, height)`` world: a sparse grid plus a dense downtown quarter."""
    width, height = size
    roads: list[Road] = []
    for horizontal, extent in ((True, height), (False, width)):
        along = width if horizontal else height
        # at least one road per axis, however small the world
        pos = rng.uniform(0.3, 0.8) * min(spacing, extent)
        while pos < extent:
            curved = rng.random() < 0.35
            amp = rng.uniform(0.05, 0.18) * spacing if curved else 0.0
            roads.append(
                Road(horizontal, pos, amp, rng.uniform(1.2, 2.5) * along, rng.uniform(0, 2 * np.pi))
            )
            # downtown: the first half of each axis has twice the roads
            dense = pos < extent / 2
            pos += rng.uniform(0.7, 1.3) * spacing / (2.0 if dense else 1.0)
    return roads


def _crossing(h: Road, v: Road) -> tuple[float, float]:
    """Where east-west road ``h`` meets north-south road ``v`` (fixed-point iteration)."""
    x = v.offset
    for _ in range(50):
        y = float(h.across(np.array([x]))[0])
        x_new = float(v.across(np.array([y]))[0])
        if abs(x_new - x) < 1e-6:
            break
        x = x_new
    return x, float(h.across(np.array([x]))[0])


def road_graph(roads: list[Road], size: tuple[int, int], step: float = 4.0) -> nx.Graph:
    """Junction graph: nodes are crossings and border ends, edges carry an ``Edge`` polyline.

    Nodes have attribute ``pos`` (world x, y) and ``border`` (True at the world's edge).
    """
    width, height = size
    import networkx as nx  # a quarter second of imports: only when a video is rendered

    graph = nx.Graph()
    hs = [i for i, r in enumerate(roads) if r.horizontal]
    vs = [i for i, r in enumerate(roads) if not r.horizontal]
    cross = {(i, j): _crossing(roads[i], roads[j]) for i in hs for j in vs}  # once per pair
    for ri, road in enumerate(roads):
        along = width if road.horizontal else height
        stops = [0.0, float(along)]
        for oi in vs if road.horizontal else hs:
            x, y = cross[(ri, oi)] if road.horizontal else cross[(oi, ri)]
            t = x if road.horizontal else y
            if 0 < t < along:
                stops.append(t)
        stops.sort()
        for a, b in itertools.pairwise(stops):
            if b - a < 1.0:
                continue
            n = max(int((b - a) / step), 1)
            pts = road.points(np.linspace(a, b, n + 1))
            arclen = np.concatenate(
                [[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
            )
            u, w = _node(graph, pts[0], size), _node(graph, pts[-1], size)
            if u != w:
                graph.add_edge(u, w, edge=Edge(pts, arclen), road=ri, ends=(u, w))
    return graph


def _node(graph: nx.Graph, p: np.ndarray, size: tuple[int, int]) -> tuple[int, int]:
    """The node at world point ``p`` (rounded, so crossings computed twice coincide)."""
    key = (round(p[0]), round(p[1]))
    if key not in graph:
        border = p[0] <= 0.5 or p[1] <= 0.5 or p[0] >= size[0] - 0.5 or p[1] >= size[1] - 0.5
        graph.add_node(key, pos=np.asarray(p, dtype=float), border=bool(border))
    return key
