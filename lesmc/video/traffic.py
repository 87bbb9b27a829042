"""Vehicles driving on the road network: turns, stops at junctions, overtaking.

Each vehicle follows a random route through the junction graph on the right-hand
lane of its direction, keeps a desired speed (0-25 m/s), brakes to stop at some
junctions, follows or overtakes slower vehicles ahead. Positions are in world
pixels, speeds in metres per second.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import networkx as nx

from lesmc.video.roads import Edge

LANE_M = 3.5  #: lane width in metres (the right-hand lane centre is LANE_M / 2 off the axis)
ACCEL = 2.5  #: m/s^2
BRAKE = 4.0  #: m/s^2


@dataclass
class Vehicle:
    """One simulated vehicle and its driving state."""

    vid: int
    node_from: tuple[int, int]
    node_to: tuple[int, int]
    s: float  # arc length driven along the current edge, world px
    speed: float  # m/s
    desired: float  # m/s
    length_px: float
    width_px: float
    intensity: float  # grey level 0..255 of the body
    stop_left: float = 0.0  # seconds still to wait at the junction ahead/at
    will_stop: bool = False
    lane: float = 1.0  # +1 right-hand lane, -1 overtaking on the opposite lane
    history: list[tuple[float, float]] = field(default_factory=list)


def _tier(rng: np.random.Generator, tiers: list[tuple[float, float, float]]) -> float:
    """Pick a tier by cumulative probability, then a uniform value in its (low, high)."""
    u = rng.random()
    for cum, low, high in tiers:
        if u < cum:
            return float(rng.uniform(low, high))
    return float(rng.uniform(tiers[-1][1], tiers[-1][2]))


class Traffic:
    """All vehicles of the world, advanced together in small time steps."""

    def __init__(
        self, graph: nx.Graph, rng: np.random.Generator, count: int, gsd: float, dense_x: float
    ) -> None:
        self.graph = graph
        self.rng = rng
        self.gsd = gsd
        self.dense_x = dense_x
        self.vehicles: list[Vehicle] = []
        self.next_id = 0
        self.borders = [  # where replacement vehicles enter
            n for n, d in graph.nodes(data=True) if d["border"] and graph.degree(n) > 0
        ]
        edges = list(graph.edges)
        lengths = np.array([graph.edges[e]["edge"].length for e in edges])
        for _ in range(count):
            u, w = edges[rng.choice(len(edges), p=lengths / lengths.sum())]
            if rng.random() < 0.5:
                u, w = w, u
            s = rng.uniform(0, graph.edges[u, w]["edge"].length)
            self.vehicles.append(self._new(u, w, s))

    def _new(self, u: tuple[int, int], w: tuple[int, int], s: float) -> Vehicle:
        rng = self.rng
        desired = _tier(rng, [(0.3, 5, 11), (0.8, 11, 18), (1.0, 18, 25)])
        if max(self.graph.nodes[u]["pos"]) < self.dense_x:
            desired *= 0.7  # downtown traffic is slower
        # motorbikes, cars, vans and lorries; WAMI pixels make all of them 3-9 px long
        length_m = float(
            rng.choice(
                [rng.uniform(1.8, 2.4), rng.uniform(3.6, 4.9), rng.uniform(5.0, 7.0)],
                p=[0.1, 0.75, 0.15],
            )
        )
        length_px = float(np.clip(length_m / self.gsd, 3.0, 9.0))
        intensity = _tier(rng, [(0.45, 15, 55), (0.85, 185, 250), (1.0, 110, 150)])  # grey
        v = Vehicle(
            self.next_id,
            u,
            w,
            s,
            speed=desired * rng.uniform(0.5, 1.0),
            desired=desired,
            length_px=length_px,
            width_px=max(2.0, min(0.45 * length_px, 4.0)),
            intensity=intensity,
        )
        self.next_id += 1
        return v

    def edge(self, v: Vehicle) -> tuple[Edge, bool]:
        """The edge a vehicle is on and whether it drives it against the polyline direction."""
        data = self.graph.edges[v.node_from, v.node_to]
        return data["edge"], data["ends"][0] != v.node_from

    def pose(self, v: Vehicle) -> tuple[np.ndarray, np.ndarray]:
        """World position (lane-offset) and unit heading of a vehicle."""
        e, rev = self.edge(v)
        pos, tan = e.at(e.length - v.s if rev else v.s)
        heading = -tan if rev else tan
        right = np.array([-heading[1], heading[0]])  # image y points down: right of travel
        return pos + right * v.lane * (LANE_M / 2) / self.gsd, heading

    def step(self, dt: float, substeps: int = 4) -> None:
        """Advance every vehicle by ``dt`` seconds."""
        h = dt / substeps
        for _ in range(substeps):
            self._substep(h)

    def _substep(self, h: float) -> None:
        groups: dict[tuple[tuple[int, int], tuple[int, int]], list[Vehicle]] = {}
        for v in self.vehicles:
            groups.setdefault((v.node_from, v.node_to), []).append(v)
        for v in list(self.vehicles):
            e, _ = self.edge(v)
            remaining_m = (e.length - v.s) * self.gsd
            target = v.desired
            if v.will_stop:
                target = min(target, np.sqrt(2 * BRAKE * max(remaining_m - 1.0, 0.0)))
            ahead = [o for o in groups[(v.node_from, v.node_to)] if o.s > v.s and o is not v]
            if ahead and v.lane > 0:
                lead = min(ahead, key=lambda o: o.s)
                gap_m = (lead.s - v.s) * self.gsd
                if gap_m < 30:
                    oncoming = groups.get((v.node_to, v.node_from), [])
                    clear = all(abs((e.length - o.s) - v.s) * self.gsd > 80 for o in oncoming)
                    if v.desired > lead.speed + 3 and remaining_m > 60 and clear:
                        v.lane = -1.0  # pull out and overtake
                    else:
                        target = min(target, lead.speed if gap_m > 8 else 0.0)
            elif v.lane < 0 and all(
                o.s < v.s - 12 / self.gsd or o.s > v.s + 30 / self.gsd
                for o in ahead + [o for o in groups[(v.node_from, v.node_to)] if o.s < v.s]
            ):
                v.lane = 1.0  # back into the right-hand lane
            if v.stop_left > 0:
                v.stop_left -= h
                target = 0.0
            rate = ACCEL if target > v.speed else BRAKE
            v.speed = min(max(float(target), v.speed - rate * h), v.speed + rate * h)  # clip
            v.s += v.speed * h / self.gsd
            if v.s >= e.length:
                self._arrive(v, v.s - e.length)

    def _arrive(self, v: Vehicle, overshoot: float) -> None:
        """At a junction: wait if asked to, take the next edge (no U-turn), or respawn."""
        if v.will_stop:
            v.will_stop = False
            v.stop_left = self.rng.uniform(2.0, 8.0)
            overshoot = 0.0
        node = v.node_to
        if self.graph.nodes[node]["border"]:
            self.vehicles.remove(v)
            self._respawn()
            return
        prev = v.node_from
        choices = [n for n in self.graph.neighbors(node) if n != prev] or [prev]
        come = self.graph.nodes[node]["pos"] - self.graph.nodes[prev]["pos"]
        # prefer going straight on: weight by alignment with the incoming direction
        weights = []
        for n in choices:
            go = self.graph.nodes[n]["pos"] - self.graph.nodes[node]["pos"]
            cos = float(np.dot(come, go) / (np.linalg.norm(come) * np.linalg.norm(go) + 1e-9))
            weights.append(1.0 + 2.0 * max(cos, 0.0))
        p = np.array(weights) / sum(weights)
        nxt = choices[self.rng.choice(len(choices), p=p)]
        v.node_from, v.node_to, v.s, v.lane = node, nxt, overshoot, 1.0
        v.will_stop = self.rng.random() < 0.25

    def _respawn(self) -> None:
        u = self.borders[self.rng.integers(len(self.borders))]
        w = next(iter(self.graph.neighbors(u)))
        self.vehicles.append(self._new(u, w, 0.0))
