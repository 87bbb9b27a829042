"""Synthetic Wide Area Motion Imagery: a deterministic stand-in for WPAFB 2009.

The world is a textured ground plane (fields, roads with lane markings) with
raised buildings and trees, filmed by a camera circling high above it (paper
section 6.1: greyscale, 1.25 Hz, vehicles under 10x10 pixels). Each frame is the
ground warped by the frame's homography, then vehicles, then raised objects
whose roofs shift with the camera (parallax), then illumination drift, blur and
sensor noise. Frames are rendered and written as they come, two or three in flight
at a time (one drawn, one through the sensor, one being encoded), so the memory used
is a few frames' worth whatever the length of the video. See docs/synthetic.md.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from lesmc.video import DEFAULT_DENSITY
from lesmc.video import FPS as FPS  # re-exported: lives in lesmc.video for the CLI's help
from lesmc.video.roads import make_roads, road_graph
from lesmc.video.traffic import LANE_M, Traffic, Vehicle

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


#: Rows of noise drawn at a time (as float64, then added as float32): 256 rows of a
#: 2048-wide frame are 4 MB, against 16 MB for 1,024 rows. The values are the same
#: whatever the band (one generator, drawn in order; tests/test_video.py).
NOISE_BAND = 256


@dataclass(frozen=True)
class SynthConfig:
    """What to generate. Lengths in pixels unless named ``_m`` (metres)."""

    frames: int = 30
    width: int = 2048
    height: int = 2048
    seed: int = 1
    density: float = DEFAULT_DENSITY  #: vehicles per 100 m of road (both directions)
    gsd_m: float = 0.6  #: ground sampling distance, metres per pixel
    altitude_m: float = 2500.0
    orbit_radius_m: float = 2000.0
    platform_speed_mps: float = 60.0
    noise: float = 2.0  #: sensor noise sd, grey levels
    blur: float = 0.6  #: optical blur sd, pixels
    depth: int = 8  #: 8 (PNG) or 16 (TIFF)


@dataclass
class Raised:
    """A building (polygon footprint) or tree (circle) that stands ``height_m`` high."""

    outline: np.ndarray  # world px, (n, 2)
    height_m: float
    roof: float  # grey level
    wall: float  # grey level of the walls; negative for trees (only the canopy is seen)


@dataclass
class FrameTruth:
    """What is really in one frame: vehicles in frame coordinates and the camera motion."""

    step: int
    vehicles: list[dict[str, Any]]
    to_prev: list[list[float]] | None


class World:
    """The static ground, the road network, the raised objects and the traffic."""

    def __init__(self, cfg: SynthConfig) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(cfg.seed)
        diag = math.hypot(cfg.width, cfg.height)
        side = int(diag * 1.15) + 64
        self.size = (side, side)
        spacing = 220.0 / cfg.gsd_m  # roads every ~220 m, ~110 m downtown
        roads = make_roads(self.rng, self.size, spacing)
        self.graph = road_graph(roads, self.size)
        road_px = sum(d["edge"].length for _, _, d in self.graph.edges(data=True))
        count = int(cfg.density * road_px * cfg.gsd_m / 100.0)
        self.traffic = Traffic(self.graph, self.rng, count, cfg.gsd_m, side / 2)
        self.ground = self._ground()
        self.raised = self._raised()

    # -- static content -------------------------------------------------------------
    def _ground(self) -> np.ndarray:
        """Fields (Voronoi patches), low and high frequency texture, roads, markings (uint8)."""
        w, h = self.size
        rng = self.rng
        # fields: nearest seed point on a coarse grid, scaled up
        coarse = (max(w // 8, 8), max(h // 8, 8))
        seeds = rng.uniform(0, 1, size=(max(int(w * h / 400**2), 8), 2)) * coarse
        yy, xx = np.mgrid[0 : coarse[1], 0 : coarse[0]]
        from scipy.spatial import cKDTree  # here: 0.45 s of imports verify's start need not pay

        _, idx = cKDTree(seeds).query(np.stack([xx.ravel(), yy.ravel()], axis=1))
        tones = rng.uniform(70, 170, size=len(seeds)).astype(np.float32)
        fields = tones[idx].reshape(coarse[1], coarse[0]).astype(np.uint8)  # 8 bit, then scale
        ground = cv2.resize(fields, (w, h), interpolation=cv2.INTER_NEAREST)
        del fields, idx, yy, xx
        for cells, amp in ((w // 64, 18.0), (w // 6, 8.0)):
            low = rng.normal(128, amp, size=(max(cells * h // w, 2), max(cells, 2)))
            low_u8 = low.clip(0, 255).astype(np.uint8)
            low_img = cv2.resize(low_u8, (w, h), interpolation=cv2.INTER_CUBIC)
            # ground + low - 128, saturated once at the end
            ground = cv2.addWeighted(ground, 1.0, low_img, 1.0, -128.0)
            del low_img
        self._grain(ground, 6.0)
        road_px = max(round(2 * LANE_M / self.cfg.gsd_m), 3)
        for _, _, d in self.graph.edges(data=True):
            pts = np.round(d["edge"].points * 16).astype(np.int32)
            cv2.polylines(ground, [pts], False, 95, road_px + 2, cv2.LINE_AA, 4)
            cv2.polylines(ground, [pts], False, 75, road_px, cv2.LINE_AA, 4)
        for _, _, d in self.graph.edges(data=True):
            pts = d["edge"].points
            for a in range(0, len(pts) - 3, 6):  # dashed centre line
                seg = np.round(pts[a : a + 3] * 16).astype(np.int32)
                cv2.polylines(ground, [seg], False, 150, 1, cv2.LINE_AA, 4)
        out: np.ndarray = ground
        return out

    def _grain(self, img: np.ndarray, sd: float) -> None:
        """Add fine texture in bands so no full-size float copy is ever made."""
        for r in range(0, img.shape[0], NOISE_BAND):
            block = img[r : r + NOISE_BAND].astype(np.float32)
            block += self.rng.normal(0, sd, size=block.shape).astype(np.float32)
            img[r : r + NOISE_BAND] = block.clip(0, 255).astype(np.uint8)

    def _near_road(self, p: np.ndarray, tree: cKDTree, clearance: float) -> bool:
        return bool(tree.query(p)[0] < clearance)

    def _raised(self) -> list[Raised]:
        """Buildings off the roads (dense downtown) and trees; none stands on a road."""
        rng = self.rng
        w, h = self.size
        road_pts = np.concatenate([d["edge"].points for _, _, d in self.graph.edges(data=True)])
        from scipy.spatial import cKDTree

        tree = cKDTree(road_pts)
        gsd = self.cfg.gsd_m
        out: list[Raised] = []
        n_build = int(w * h * gsd * gsd / 4000)  # about one per 63 m x 63 m
        for _ in range(n_build):
            downtown = rng.random() < 0.6
            c = rng.uniform([0, 0], [w / 2, h / 2] if downtown else [w, h])
            half = rng.uniform(6, 20, size=2) / gsd
            if self._near_road(c, tree, float(np.hypot(*half)) + LANE_M / gsd + 2):
                continue
            ang = rng.uniform(0, np.pi)
            rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
            box = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
            height = rng.uniform(15, 45) if downtown else rng.uniform(5, 15)
            roof = rng.uniform(60, 230)
            out.append(Raised(c + box @ rot.T, height, roof, roof * rng.uniform(0.4, 0.7)))
        for _ in range(n_build // 2):
            c = rng.uniform([0, 0], [w, h])
            r = rng.uniform(2, 5) / gsd
            if self._near_road(c, tree, r + LANE_M / gsd + 1):
                continue
            t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
            circle = c + r * np.stack([np.cos(t), np.sin(t)], axis=1)
            out.append(Raised(circle, rng.uniform(6, 15), rng.uniform(35, 70), -1.0))
        return out

    # -- the camera ------------------------------------------------------------------
    def camera(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``k``'s homography world -> frame and the camera's nadir (world px)."""
        cfg = self.cfg
        w, h = self.size
        centre = np.array([w / 2, h / 2])
        t = k / FPS
        phi = cfg.platform_speed_mps * t / cfg.orbit_radius_m
        nadir = centre + cfg.orbit_radius_m / cfg.gsd_m * np.array([np.cos(phi), np.sin(phi)])
        drift = (
            0.04 * min(cfg.width, cfg.height) * np.array([np.sin(0.05 * k), np.cos(0.037 * k) - 1])
        )
        look = centre + drift
        theta = 0.3 * phi  # the gimbal removes most of the orbit's rotation
        scale = 1.0 + 0.01 * np.sin(0.11 * k)
        tilt = 2e-6 * 2048 / max(cfg.width, cfg.height)
        persp = tilt * np.array([np.cos(phi), np.sin(phi)])
        c, s = np.cos(theta), np.sin(theta)
        to_look = np.array([[1, 0, -look[0]], [0, 1, -look[1]], [0, 0, 1]], float)
        rot = np.array([[c * scale, -s * scale, 0], [s * scale, c * scale, 0], [0, 0, 1]])
        proj = np.array([[1, 0, 0], [0, 1, 0], [persp[0], persp[1], 1]])
        to_frame = np.array([[1, 0, cfg.width / 2], [0, 1, cfg.height / 2], [0, 0, 1]], float)
        return to_frame @ proj @ rot @ to_look, nadir

    # -- rendering -------------------------------------------------------------------
    def render(self, k: int) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Frame ``k`` as float32 grey levels, its homography and the vehicles in view."""
        frame, H, truth = self.scene(k)
        self.sensor(frame, k)
        return frame, H, truth

    def scene(self, k: int) -> tuple[np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """:meth:`render` before the sensor: ground, vehicles and raised objects."""
        cfg = self.cfg
        H, nadir = self.camera(k)
        img = cv2.warpPerspective(self.ground, H, (cfg.width, cfg.height), flags=cv2.INTER_LINEAR)
        frame = img.astype(np.float32)
        del img
        truth = self._draw_vehicles(frame, H)
        cover = self._draw_raised(frame, H, nadir)
        for v in truth:  # a vehicle under a roof or canopy is in the truth but not visible
            v["occluded"] = bool(cover[int(v["y"]), int(v["x"])])
        return frame, H, truth

    def _draw_vehicles(self, frame: np.ndarray, H: np.ndarray) -> list[dict[str, Any]]:
        """Blend each vehicle in the frame into it; their truth records.

        Most of the world's vehicles are outside the frame: one projection of all their
        positions skips those more than a pixel outside, and the rest are projected one
        by one, as they are drawn (so the bits do not depend on the batch's arithmetic).
        """
        cfg = self.cfg
        out: list[dict[str, Any]] = []
        poses = [self.traffic.pose(v) for v in self.traffic.vehicles]
        if not poses:
            return out
        near = _apply(H, np.array([pos for pos, _ in poses]))
        near_x = (near[:, 0] >= -1) & (near[:, 0] < cfg.width + 1)
        near_y = (near[:, 1] >= -1) & (near[:, 1] < cfg.height + 1)
        for v, (pos, heading), maybe in zip(
            self.traffic.vehicles, poses, near_x & near_y, strict=True
        ):
            if maybe:
                p = _apply(H, pos[None])[0]
                ahead = _apply(H, (pos + heading)[None])[0] - p
                if 0 <= p[0] < cfg.width and 0 <= p[1] < cfg.height:
                    out.append(self._draw_vehicle(frame, v, p, ahead))
        return out

    def _draw_vehicle(
        self, frame: np.ndarray, v: Vehicle, p: np.ndarray, ahead: np.ndarray
    ) -> dict[str, Any]:
        """Blend one vehicle at frame position ``p``, heading ``ahead`` (one world pixel
        projected), as an anti-aliased rotated box (4x4 supersampling); its truth."""
        cfg = self.cfg
        scale = float(np.linalg.norm(ahead))
        d = ahead / max(scale, 1e-9)
        half_l, half_w = v.length_px * scale / 2, v.width_px * scale / 2
        r = math.ceil(half_l) + 2
        x0, y0 = int(p[0]) - r, int(p[1]) - r
        xs = np.arange(x0, x0 + 2 * r + 1)[:, None] + _SUBSAMPLES[None]
        ys = np.arange(y0, y0 + 2 * r + 1)[:, None] + _SUBSAMPLES[None]
        gx = xs.reshape(-1)[None, :] - p[0]
        gy = ys.reshape(-1)[:, None] - p[1]
        along = gx * d[0] + gy * d[1]
        across = -gx * d[1] + gy * d[0]
        inside = (np.abs(along) <= half_l) & (np.abs(across) <= half_w)
        n = 2 * r + 1
        # the fraction of the 16 subsamples inside: a count over 16, exact in float32
        cover = inside.reshape(n, 4, n, 4).sum(axis=(1, 3), dtype=np.float32) / 16
        ya, yb = max(y0, 0), min(y0 + n, cfg.height)
        xa, xb = max(x0, 0), min(x0 + n, cfg.width)
        c = cover[ya - y0 : yb - y0, xa - x0 : xb - x0]
        patch = frame[ya:yb, xa:xb]
        patch *= 1 - c
        patch += c * v.intensity
        vel = v.speed / cfg.gsd_m * scale * d  # frame px per second
        tone = "dark" if v.intensity < 80 else "bright" if v.intensity > 170 else "mid"
        return {
            "id": v.vid,
            "x": round(float(p[0]), 3),
            "y": round(float(p[1]), 3),
            "vx": round(float(vel[0]), 3),
            "vy": round(float(vel[1]), 3),
            "speed_mps": round(v.speed, 3),
            "length_px": round(v.length_px * scale, 2),
            "tone": tone,
        }

    def _draw_raised(self, frame: np.ndarray, H: np.ndarray, nadir: np.ndarray) -> np.ndarray:
        """Walls then roof of each raised object, the roof displaced away from the nadir.

        Returns the mask of pixels the raised objects cover.
        """
        cover = np.zeros(frame.shape, np.uint8)
        cfg = self.cfg
        alt = cfg.altitude_m
        shift = 16.0
        margin = 200
        for obj in self.raised:
            base = _apply(H, obj.outline)
            if (
                base[:, 0].max() < -margin
                or base[:, 1].max() < -margin
                or base[:, 0].min() > cfg.width + margin
                or base[:, 1].min() > cfg.height + margin
            ):
                continue
            top_w = obj.outline + (obj.outline - nadir) * (obj.height_m / (alt - obj.height_m))
            top = _apply(H, top_w)
            n = len(base) if obj.wall >= 0 else 0
            for i in range(n):
                j = (i + 1) % n
                quad = np.array([base[i], base[j], top[j], top[i]])
                poly = np.round(quad * shift).astype(np.int32)
                cv2.fillConvexPoly(frame, poly, obj.wall, cv2.LINE_8, 4)
                cv2.fillConvexPoly(cover, poly, 1, cv2.LINE_8, 4)
            poly = np.round(top * shift).astype(np.int32)
            cv2.fillConvexPoly(frame, poly, obj.roof, cv2.LINE_8, 4)
            cv2.fillConvexPoly(cover, poly, 1, cv2.LINE_8, 4)
        return cover

    def sensor(self, frame: np.ndarray, k: int) -> None:
        """Slow illumination drift, optical blur and sensor noise, in place."""
        cfg = self.cfg
        gain = 1.0 + 0.04 * math.sin(2 * math.pi * k / 40.0) + 0.002 * k
        tilt = 0.03 * math.sin(2 * math.pi * k / 55.0)
        ramp = (1 + tilt * (np.arange(cfg.width, dtype=np.float32) / cfg.width - 0.5)) * gain
        cv2.GaussianBlur(frame, (0, 0), cfg.blur, dst=frame)
        rng = np.random.default_rng([cfg.seed, k, 7])
        for r in range(0, cfg.height, NOISE_BAND):
            block = frame[r : r + NOISE_BAND]
            block *= ramp[None, :]
            block += rng.normal(0, cfg.noise, size=block.shape).astype(np.float32)


#: where each pixel is sampled, 4x4 times, to anti-alias a vehicle's box
_SUBSAMPLES = (np.arange(4) + 0.5) / 4


def _apply(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply homography ``H`` to ``(n, 2)`` points."""
    q = np.asarray(pts, float) @ H[:2, :2].T + H[:2, 2]
    wz = np.asarray(pts, float) @ H[2, :2] + H[2, 2]
    out: np.ndarray = q / wz[:, None]
    return out


def frames(cfg: SynthConfig) -> Iterator[tuple[np.ndarray, FrameTruth]]:
    """Render the video frame by frame: (image as uint8 or uint16, truth).

    Frame k's sensor (blur, drift, noise) and quantisation run on a second thread while
    frame k+1's scene is drawn: numpy's and OpenCV's work there releases the GIL, the
    scene's is mostly Python. The bits are those of one after the other
    (tests/test_video.py); the default video renders in about 0.6x the time.
    """
    world = World(cfg)
    dt = 1.0 / FPS
    prev_h: np.ndarray | None = None
    pending: tuple[Future[np.ndarray], FrameTruth] | None = None
    with ThreadPoolExecutor(1, thread_name_prefix="lesmc-sensor") as pool:
        for k in range(cfg.frames):
            img, H, vehicles = world.scene(k)
            to_prev = None
            if prev_h is not None:
                m = prev_h @ np.linalg.inv(H)
                to_prev = (m / m[2, 2]).round(12).tolist()
            prev_h = H
            world.traffic.step(dt)
            done = pending
            pending = (pool.submit(_finish, world, img, k), FrameTruth(k, vehicles, to_prev))
            del img
            if done is not None:
                yield done[0].result(), done[1]
        if pending is not None:
            yield pending[0].result(), pending[1]


def _finish(world: World, img: np.ndarray, k: int) -> np.ndarray:
    """Frame ``k``'s scene through the sensor, quantised to the video's depth."""
    world.sensor(img, k)
    # in place: no frame-sized temporaries (large frames are 480 MB as float32)
    if world.cfg.depth == 16:
        img *= 257.0
        np.clip(img, 0, 65535, out=img)
        return img.astype(np.uint16)
    np.rint(img, out=img)
    np.clip(img, 0, 255, out=img)
    return img.astype(np.uint8)


def frame_name(k: int, depth: int) -> str:
    return f"frame_{k:05d}." + ("tif" if depth == 16 else "png")


def truth_header(cfg: SynthConfig) -> dict[str, Any]:
    return {
        "format": "lesmc-truth",
        "version": 1,
        "dt": 1.0 / FPS,
        "config": asdict(cfg),
        "units": {
            "x,y": "frame pixels",
            "vx,vy": "frame pixels per second",
            "to_prev": "homography from this frame's pixels to the previous frame's",
        },
    }


def render_into(
    cfg: SynthConfig, tmp: Path, out_dir: Path, progress: Callable[[], None] | None = None
) -> None:
    """The frames and truth.json of :func:`write_video`, written into the staging
    directory ``tmp`` (``out_dir``: where they will be moved, the name errors give)."""
    truth: list[dict[str, Any]] = []
    with ThreadPoolExecutor(1, thread_name_prefix="lesmc-png") as writer:
        last: Future[None] | None = None
        for img, ft in frames(cfg):
            name = frame_name(ft.step, cfg.depth)
            written = writer.submit(_write_frame, tmp / name, img, out_dir / name)
            truth.append(
                {"step": ft.step, "file": name, "to_prev": ft.to_prev, "vehicles": ft.vehicles}
            )
            if last is not None:
                _done(last, progress)
            last = written
        if last is not None:
            _done(last, progress)
    doc = truth_header(cfg) | {"frames": truth}
    (tmp / "truth.json").write_text(json.dumps(doc, separators=(",", ":")) + "\n")


def _write_frame(path: Path, img: np.ndarray, shown: Path) -> None:
    """One frame's file (``shown``: its name in errors, where it will be moved)."""
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {shown}")


def _done(written: Future[None], progress: Callable[[], None] | None) -> None:
    """Wait for a frame's file (its error is raised here), then count it."""
    written.result()
    if progress is not None:
        progress()
