"""``SimulatedTable``: the built-in RGB-D source — a scripted table scene rendered with a depth-sensor model.

Frames are rendered on demand (``render(index)``, random access) and are bit-identical for the same
scenario, seed and options. Each frame carries its ground truth in ``frame.meta["groundtruth"]``:

* ``"poses"``: ``{part name: Pose}`` in the camera frame (x right, y down, z forward, metres);
* ``"hand_box"``: ``[u0, v0, u1, v1]`` pixel bounds of the visible hand (end-exclusive) or ``None``;
* hand-tracking scenarios only (``hands-s1``…``s3``): ``"hand_boxes"``, a list of ``[u0, v0, u1, v1]`` palm
  boxes (end-exclusive pixels; the tight box of the visible palm and finger pixels, wrist outward, forearm
  excluded), one per visible hand; ``"hand_box_ids"``, the index of each box's hand (stable over the scenario);
  ``"skin_mask"``, uint8 H×W: 0 = no skin, ``k + 1`` = palm/fingers of hand k, ``128 + k + 1`` = the bare
  forearm of hand k (the rendered geometry, before motion blur);
* ``"visible"``: ``{part name: fraction 0..1}`` of the part's unoccluded projected area that is visible
  (0 when it is out of the image or hidden by the hand or another part);
* ``"table_plane"``: ``{"normal": [3], "offset": d}``, the table plane ``n·p + d = 0`` in this frame's camera
  frame (``n`` the upward unit normal);
* ``"camera_pose"``: the camera's Pose in the simulator's table frame (the table frame of the nominal camera
  placement, fixed in the scene; constant unless ``SimOptions.camera_motion`` moves the camera).

With ``SimOptions.camera_motion`` ``"sway"`` or ``"handheld"`` (see :mod:`.camera_motion`) every frame is
rendered from that frame's camera pose: the table and floor are ray-cast again for each frame (about 5–10 ms
more per frame); with ``"none"`` they are rendered once and frames are bit-identical to a fixed camera.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose, normalize_quat
from tracker.sources.base import FrameSource
from tracker.sources.simulator import rasterizer as rz
from tracker.sources.simulator.camera_motion import CAMERA_MOTIONS, CameraMotion
from tracker.sources.simulator.hand import N_ARM_PRIMS, Box, Capsule, hand_primitives
from tracker.sources.simulator.scenarios import (
    EXTRA_PART_COLORS,
    ConnectionEvent,
    ScenarioInfo,
    ScriptBuilder,
    ScriptSettings,
    Timeline,
    get_scenario,
)
from tracker.sources.simulator.scene import (
    AMBIENT,
    DIFFUSE,
    LIGHT_DIR_TABLE,
    BackgroundCaster,
    CameraPlacement,
    render_background,
)
from tracker.sources.simulator.sensor_model import ColorSensorModel, DepthSensorModel

FPS = 30.0
"""Frame rate of the simulator; frame ``i`` has timestamp ``i / FPS`` seconds."""


@dataclass(frozen=True)
class SimOptions:
    """Options of the simulated table.

    * ``speed``: motion speed factor of the hand (1 = natural, 2 = twice as fast).
    * ``occlusion``: amount of occlusion by the hand, 0..2 (1 = default). Scales the hand's width
      (0.75 + 0.25·occlusion), the time it hovers over the target before lowering a part (0.4 s ·
      occlusion) and, from 1.5 on, routes the carried part over another resting part.
    * ``excursions``: when True, the hand carries the part beyond the nearer left/right image border
      before placing it (in about 60 % of the moves; the part is out of view for about 0.7–1.2 s).
    * ``camera_distance``: metres from the table centre (None: seeded choice in [0.6, 0.9]).
    * ``camera_elevation_deg``: camera looking down at this angle (None: seeded choice in [40, 60]).
    * ``width``, ``height``, ``focal``: image size and focal length in pixels (640×480, 525).
    * ``static_duration``: length of the ``static`` scenario, seconds.
    * ``free_moves``: number of pick-and-place moves in the ``free`` scenario.
    * ``extra_parts``: further rigid parts (boxes such as the 2×2×10 cm rod, or meshes) lying on the table.
    * ``shadows``: soft shadows of the parts and the hand on the table.
    * ``show_hand``: render the hand (False: parts move as if carried by an invisible hand).
    * ``depth_model`` / ``color_model``: the sensor models (see :mod:`.sensor_model`).
    * ``camera_motion``: ``"none"`` (fixed camera), ``"sway"`` (slow seeded motion of a few cm and degrees
      around the nominal placement, periods 4–14 s) or ``"handheld"`` (sway plus a small faster jitter);
      see :mod:`.camera_motion`. The script (where parts lie and move) is the same for every value.
    """

    speed: float = 1.0
    occlusion: float = 1.0
    excursions: bool = False
    camera_distance: float | None = None
    camera_elevation_deg: float | None = None
    width: int = 640
    height: int = 480
    focal: float = 525.0
    static_duration: float = 10.0
    free_moves: int = 6
    extra_parts: tuple[PartSpec, ...] = ()
    shadows: bool = True
    show_hand: bool = True
    depth_model: DepthSensorModel = field(default_factory=DepthSensorModel)
    color_model: ColorSensorModel = field(default_factory=ColorSensorModel)
    camera_motion: str = "none"

    def __post_init__(self) -> None:
        if self.camera_motion not in CAMERA_MOTIONS:
            raise ValueError(f"SimOptions.camera_motion must be one of {', '.join(CAMERA_MOTIONS)}, "
                             f"got {self.camera_motion!r}")
        if not 0.05 <= self.speed <= 20:
            raise ValueError(f"SimOptions.speed must be within 0.05–20, got {self.speed}")
        if not 0.0 <= self.occlusion <= 2.0:
            raise ValueError(f"SimOptions.occlusion must be within 0–2, got {self.occlusion}")
        if self.static_duration <= 0:
            raise ValueError("SimOptions.static_duration must be positive")


class _MeshCache:
    def __init__(self, part: PartSpec) -> None:
        mesh = part.load_mesh()
        self.vertices = np.asarray(mesh.vertices, float)
        self.faces = np.asarray(mesh.faces, np.int64)
        self.normals = np.asarray(mesh.face_normals, float)


class SimulatedTable(FrameSource):
    """A scripted simulated table (see module docstring). ``scenario`` is one of :func:`list_scenarios`.

    ``realtime=True`` paces iteration at 30 fps; ``n_frames`` limits the length (default: the whole script).
    Rendering reuses internal buffers, so one instance must not render from two threads at once.
    """

    name = "sim"

    def __init__(
        self,
        scenario: str = "static",
        seed: int = 0,
        options: SimOptions | None = None,
        realtime: bool = False,
        n_frames: int | None = None,
    ) -> None:
        self.info: ScenarioInfo = get_scenario(scenario)
        self.name = f"sim:{self.info.name}"
        self.options = options or SimOptions()
        self.seed = int(seed)
        self.realtime = bool(realtime)
        opts = self.options
        ss = np.random.SeedSequence([self.seed, 20261123])
        rng_cam, rng_script, rng_bg, rng_misc = (np.random.default_rng(s) for s in ss.spawn(4))
        dist = rng_cam.uniform(0.6, 0.9)
        elev = rng_cam.uniform(40.0, 60.0)
        self.camera = CameraPlacement(
            float(opts.camera_distance if opts.camera_distance is not None else dist),
            float(opts.camera_elevation_deg if opts.camera_elevation_deg is not None else elev),
        )
        w, h = int(opts.width), int(opts.height)
        self._intr = Intrinsics(w, h, float(opts.focal), float(opts.focal), (w - 1) / 2.0, (h - 1) / 2.0)
        self._parts = [PartSpec.cube(n, EXTRA_PART_COLORS.get(n, n)) for n in self.info.parts] + list(opts.extra_parts)
        names = [p.name for p in self._parts]
        if len(set(names)) != len(names):
            raise ValueError(f"simulator: part names must be unique, got {names}")
        self._T = self.camera.table_to_camera()
        settings = ScriptSettings(
            speed=opts.speed,
            occlusion=opts.occlusion,
            excursions=opts.excursions,
            static_duration=opts.static_duration,
            free_moves=opts.free_moves,
        )
        builder = ScriptBuilder(self.info, self._parts, self._T, self._intr, rng_script, settings)
        self.timeline: Timeline = builder.build()
        self._n_total = int(np.ceil(self.timeline.duration * FPS))
        self.n_frames = self._n_total if n_frames is None else max(0, int(n_frames))
        self._phase = float(rng_misc.uniform(0, 2 * np.pi))
        self._meshes = {p.name: _MeshCache(p) for p in self._parts if p.box is None}

        # the camera motion has its own random stream, so the others (and a fixed camera's frames) are unchanged
        self._motion = CameraMotion(opts.camera_motion, np.random.default_rng([self.seed, 20261123, 77]))
        self._ids = np.full((h, w), -1, np.int16)
        self._caster: BackgroundCaster | None = None
        if self._motion.moving:
            self._caster = BackgroundCaster(self._intr, rng_bg)
            self._bg = None
            self._depth = np.full((h, w), np.inf, np.float32)
            self._cos = np.ones((h, w), np.float32)
            self._color = np.zeros((h, w, 3), np.float32)
            self._bg_table = np.zeros((h, w), np.bool_)
        else:
            bg = render_background(self._intr, self.camera, rng_bg)
            self._bg = bg
            self._bg_table = bg.table
            self._depth = bg.depth.copy()
            self._cos = bg.cosang.copy()
            self._color = bg.color.copy()
        if self.info.hands is not None:  # hand scenarios: a blue-grey cloth on the (skin-coloured) wooden table
            if self._caster is not None:
                self._caster.tex = np.ascontiguousarray(table_cloth(self._caster.tex))
            else:
                self._bg.color[self._bg.table] = table_cloth(self._bg.color[self._bg.table])
                self._color = self._bg.color.copy()
        self._plane = self.camera.table_plane()
        self._dirty: list[tuple[int, int, int, int]] = []  # rectangles drawn into by the last frame (every buffer)
        self._dirty_color: list[tuple[int, int, int, int]] = []  # … whose colour alone changed (shadows, blur)
        self._closed = False
        self._blur_scratch: np.ndarray | None = None  # the colour sensor model's blurred colour, reused every frame
        # fixed camera: the projector shadow of the background, and the shadow of the last frame with the rows that
        # differ from it (the rows of its geometry rectangles): only those rows are computed again (_projector_shadow)
        self._proj_bg: np.ndarray | None = None
        self._proj_shadow: np.ndarray | None = None
        self._proj_rows = np.zeros(h, np.bool_)

    # ---------------------------------------------------------------- FrameSource / public properties
    @property
    def intrinsics(self) -> Intrinsics:
        return self._intr

    @property
    def parts(self) -> list[PartSpec]:
        return list(self._parts)

    @property
    def scenario(self) -> ScenarioInfo:
        return self.info

    @property
    def table_to_camera(self) -> Pose:
        """Pose of the table frame in the camera frame (at the first frame; see :meth:`table_to_camera_at`)."""
        return self.table_to_camera_at(0)

    @property
    def table_plane(self) -> tuple[np.ndarray, float]:
        """``(n, d)``: ``n·p + d = 0`` for camera-frame points on the table, ``n`` the upward unit normal (at the
        first frame; see :meth:`table_plane_at`)."""
        return self.table_plane_at(0)

    @property
    def camera_motion(self) -> str:
        """``"none"``, ``"sway"`` or ``"handheld"`` (``SimOptions.camera_motion``)."""
        return self._motion.kind

    def camera_pose_at(self, index: int) -> Pose:
        """The camera's pose in the simulator's (fixed) table frame at frame ``index``."""
        c2t = self.camera.camera_to_table()
        if not self._motion.moving:
            return c2t
        return c2t @ self._motion.offset(index / FPS)

    def table_to_camera_at(self, index: int) -> Pose:
        """Pose of the simulator's table frame in the camera frame of frame ``index``."""
        if not self._motion.moving:
            return self._T
        return self.camera_pose_at(index).inverse()

    def table_plane_at(self, index: int) -> tuple[np.ndarray, float]:
        """``(n, d)`` of the table plane in the camera frame of frame ``index`` (``n`` up, ``n·p + d = 0``)."""
        if not self._motion.moving:
            return self.camera.table_plane()
        T = self.table_to_camera_at(index)
        n = T.R[:, 1]
        return n, -float(n @ T.t)

    @property
    def duration(self) -> float:
        """Length of the scripted scenario in seconds."""
        return float(self.timeline.duration)

    @property
    def events(self) -> list[ConnectionEvent]:
        return list(self.timeline.events)

    @property
    def initial_poses(self) -> dict[str, Pose]:
        return self.groundtruth(0)

    def groundtruth(self, index: int) -> dict[str, Pose]:
        """Every part's pose in the camera frame at frame ``index``."""
        t = index / FPS
        T = self.table_to_camera_at(index)
        return {p.name: _stable(T @ self.timeline.part_pose(p.name, t)) for p in self._parts}

    def metadata(self) -> dict[str, Any]:
        md = super().metadata()
        md.update(
            {
                "scenario": self.info.to_dict(),
                "seed": self.seed,
                "fps": FPS,
                "n_frames": self.n_frames,
                "duration": self.duration,
                "camera_distance": self.camera.distance,
                "camera_elevation_deg": self.camera.elevation_deg,
                "table_plane": {"normal": [float(v) for v in self.table_plane[0]], "offset": self.table_plane[1]},
                "parts": [p.name for p in self._parts],
                "options": {
                    "speed": self.options.speed,
                    "occlusion": self.options.occlusion,
                    "excursions": self.options.excursions,
                    "camera_motion": self._motion.kind,
                },
            }
        )
        return md

    def __len__(self) -> int:
        return self.n_frames

    def __iter__(self) -> Iterator[Frame]:
        start = time.perf_counter()
        for i in range(self.n_frames):
            if self._closed:
                return
            frame = self.render(i)
            if self.realtime:
                delay = start + i / FPS - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            yield frame

    def close(self) -> None:
        self._closed = True

    # ---------------------------------------------------------------- rendering
    def frame_key(self, index: int) -> int:
        """The per-frame random key (uint64) of frame ``index``."""
        return int(np.random.SeedSequence([self.seed, int(index)]).generate_state(1, np.uint64)[0])

    def _light(self, t: float, T: Pose) -> np.ndarray:
        """Unit direction towards the light in the camera frame whose table-to-camera pose is ``T``."""
        wob = 0.15 * np.array([np.sin(t / 5.0 + self._phase), 0.0, np.cos(t / 7.0 + self._phase)])
        lt = LIGHT_DIR_TABLE + wob
        return T.R @ (lt / np.linalg.norm(lt))

    def render_clean(self, index: int) -> dict[str, Any]:
        """Render frame ``index`` without sensor noise. Returns a dict with ``color`` (float32 0..255),
        ``depth`` (float32, inf where nothing), ``cosang``, ``ids`` (int16: part index, hand = n_parts,
        -1 background; views of internal buffers, valid until the next render), ``poses``, ``hand_box``,
        ``visible``, ``table_plane`` (n, d), ``camera_pose`` (in the table frame) and ``t``."""
        t = index / FPS
        intr = self._intr
        W, H = intr.width, intr.height
        fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy
        bg = self._bg
        if self._caster is not None:  # moving camera: ray-cast the whole background again from this frame's pose
            T = self.table_to_camera_at(index)
            self._plane = self.table_plane_at(index)
            self._caster.render(self.camera_pose_at(index), self._depth, self._cos, self._color, self._bg_table)
            self._ids.fill(-1)
        else:
            T = self._T
            if self._dirty or self._dirty_color:  # the background again where the last frame changed it
                rz.restore_rects(_rect_array(self._dirty), _rect_array(self._dirty_color), self._depth, self._cos,
                                 self._color, self._ids, bg.depth, bg.cosang, bg.color)  # fmt: skip
        dirty: list[tuple[int, int, int, int]] = []
        dirty_color: list[tuple[int, int, int, int]] = []
        light = self._light(t, T)
        n_parts = len(self._parts)
        hits = np.zeros(n_parts + 1 + 2 * len(self.timeline.hands), np.int64)
        poses: dict[str, Pose] = {}
        rects: dict[str, tuple[int, int, int, int] | None] = {}
        hull_pts: dict[str, np.ndarray] = {}
        shapes: list[tuple[np.ndarray, float]] = []

        for pid, part in enumerate(self._parts):
            pose = _stable(T @ self.timeline.part_pose(part.name, t))
            poses[part.name] = pose
            R, tt = pose.R, pose.t
            albedo = np.asarray(part.color if part.color is not None else (150, 150, 150), float)
            if part.box is not None:
                half = np.asarray(part.box, float) / 2.0
                pts = box_corners(R, tt, half)
                rect = rz.points_rect(pts, fx, fy, cx, cy, W, H)
                if rect is not None:
                    rz.render_box(self._depth, self._cos, self._color, self._ids, hits, fx, fy, cx, cy, R, tt, half,
                                  albedo, light, AMBIENT, DIFFUSE, pid, *rect, 0.0012, 0.35)  # fmt: skip
            else:
                mc = self._meshes[part.name]
                verts = mc.vertices @ R.T + tt
                pts = verts
                rect = rz.points_rect(verts, fx, fy, cx, cy, W, H)
                if rect is not None:
                    tris = np.ascontiguousarray(verts[mc.faces])
                    normals = np.ascontiguousarray(mc.normals @ R.T)
                    local = np.empty((rect[3] - rect[1], rect[2] - rect[0]), np.float32)
                    rz.render_triangles(self._depth, self._cos, self._color, self._ids, hits, local, fx, fy, cx, cy,
                                        tris, normals, albedo, light, AMBIENT, DIFFUSE, pid, *rect)  # fmt: skip
            rects[part.name] = rect
            hull_pts[part.name] = pts
            shapes.append((pts, 0.55))
            if rect is not None:
                dirty.append(rect)

        # the hand
        hand_id = n_parts
        hand_rects: list[tuple[int, int, int, int]] = []
        hp = self.timeline.active_pass(t) if self.options.show_hand else None
        if hp is not None:
            hpose, grip = hp.state(t)
            hpose = T @ hpose
            shoulder = T.transform_points(hp.shoulder[None])[0] if hp.shoulder is not None else None
            prims = hand_primitives(hpose.R, hpose.t, grip, hp.half_height, hp.half_height, hp.scale,
                                    shoulder=shoulder, mirror=hp.side < 0)  # fmt: skip
            for p in prims:
                albedo = np.asarray(p.albedo, float)
                if isinstance(p, Capsule):
                    corners = _SIGNS * p.radius
                    pts = np.concatenate([corners + p.a, corners + p.b])
                    rect = rz.points_rect(pts, fx, fy, cx, cy, W, H)
                    if rect is not None:
                        rz.render_capsule(self._depth, self._cos, self._color, self._ids, hits, fx, fy, cx, cy, p.a,
                                          p.b, p.radius, albedo, light, AMBIENT, DIFFUSE, hand_id, *rect)  # fmt: skip
                    shapes.append((pts, 0.5))
                else:
                    assert isinstance(p, Box)
                    rect = rz.box_rect(p.R, p.t, p.half, fx, fy, cx, cy, W, H)
                    if rect is not None:
                        rz.render_box(self._depth, self._cos, self._color, self._ids, hits, fx, fy, cx, cy, p.R, p.t,
                                      p.half, albedo, light, AMBIENT, DIFFUSE, hand_id, *rect, 0.0, 0.0)  # fmt: skip
                    shapes.append((box_corners(p.R, p.t, p.half), 0.5))
                if rect is not None:
                    hand_rects.append(rect)
                    dirty.append(rect)

        palm_boxes, palm_ids, skin = self._render_wandering_hands(t, T, light, hits, hand_rects, dirty, shapes)

        if self.options.shadows and shapes:
            srect = self._shadow(shapes, light)
            if srect is not None:
                dirty_color.append(srect)

        # ground truth: hand box and visible fractions
        hand_box = None
        if hand_rects:
            u0 = min(r[0] for r in hand_rects)
            v0 = min(r[1] for r in hand_rects)
            u1 = max(r[2] for r in hand_rects)
            v1 = max(r[3] for r in hand_rects)
            m = self._ids[v0:v1, u0:u1] == hand_id
            if m.any():
                rows = np.flatnonzero(m.any(axis=1))
                cols = np.flatnonzero(m.any(axis=0))
                hand_box = [int(u0 + cols[0]), int(v0 + rows[0]), int(u0 + cols[-1] + 1), int(v0 + rows[-1] + 1)]
        visible: dict[str, float] = {}
        for pid, part in enumerate(self._parts):
            rect = rects[part.name]
            front = 0
            if rect is not None:
                front = int(np.count_nonzero(self._ids[rect[1] : rect[3], rect[0] : rect[2]] == pid))
            outside = _outside_area(hull_pts[part.name], intr)
            denom = hits[pid] + outside
            visible[part.name] = float(min(1.0, front / denom)) if denom > 0 else 0.0
        if self.timeline.hands:
            self._motion_blur(t, T, dirty_color)
        self._dirty, self._dirty_color = dirty, dirty_color
        return {
            "hand_boxes": palm_boxes,
            "hand_box_ids": palm_ids,
            "skin_mask": skin,
            "t": t,
            "color": self._color,
            "depth": self._depth,
            "cosang": self._cos,
            "ids": self._ids,
            "poses": poses,
            "hand_box": hand_box,
            "visible": visible,
            "table_plane": self._plane,
            "camera_pose": self.camera_pose_at(index),
        }

    def _render_wandering_hands(self, t, T, light, hits, hand_rects, dirty, shapes):
        """Render the hands of a hand-tracking scenario; returns (palm boxes, their hand indices, skin mask or None).

        Hand k is rendered with ids ``n_parts + 1 + 2k`` (palm, fingers) and ``n_parts + 2 + 2k`` (arm) so that its
        palm box and skin mask can be read off the id buffer; the ids are then set back to ``n_parts`` (the hand id
        of :meth:`render_clean`)."""
        hands = self.timeline.hands
        if not hands or not self.options.show_hand:
            return [], [], None
        intr = self._intr
        W, H = intr.width, intr.height
        fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy
        n_parts = len(self._parts)
        rects: list[tuple[int, int, int, int]] = []
        for k, wh in enumerate(hands):
            hp = wh.path
            if not hp.t_start <= t <= hp.t_end:
                continue
            hpose, grip = hp.state(t)
            hpose = T @ hpose
            shoulder = T.transform_points(hp.shoulder[None])[0] if hp.shoulder is not None else None
            prims = hand_primitives(hpose.R, hpose.t, grip, hp.half_height, hp.half_height, hp.scale,
                                    shoulder=shoulder, mirror=hp.side < 0, albedos=wh.albedos,
                                    wrist_taper=0.4)  # fmt: skip
            for j, p in enumerate(prims):
                assert isinstance(p, Capsule)
                pid = n_parts + 1 + 2 * k + (1 if j >= len(prims) - N_ARM_PRIMS else 0)
                corners = _SIGNS * p.radius
                pts = np.concatenate([corners + p.a, corners + p.b])
                rect = rz.points_rect(pts, fx, fy, cx, cy, W, H)
                if rect is not None:
                    rz.render_capsule(self._depth, self._cos, self._color, self._ids, hits, fx, fy, cx, cy, p.a,
                                      p.b, p.radius, np.asarray(p.albedo, float), light, AMBIENT, DIFFUSE, pid,
                                      *rect)  # fmt: skip
                    rects.append(rect)
                shapes.append((pts, 0.5))
        boxes: list[list[int]] = []
        box_ids: list[int] = []
        skin = np.zeros((H, W), np.uint8)
        if not rects:
            return boxes, box_ids, skin
        u0 = min(r[0] for r in rects)
        v0 = min(r[1] for r in rects)
        u1 = max(r[2] for r in rects)
        v1 = max(r[3] for r in rects)
        ids = self._ids[v0:v1, u0:u1]
        for k, wh in enumerate(hands):
            palm = ids == n_parts + 1 + 2 * k
            if palm.any():
                rows = np.flatnonzero(palm.any(axis=1))
                cols = np.flatnonzero(palm.any(axis=0))
                boxes.append([int(u0 + cols[0]), int(v0 + rows[0]), int(u0 + cols[-1] + 1), int(v0 + rows[-1] + 1)])
                box_ids.append(k)
                skin[v0:v1, u0:u1][palm] = k + 1
            if wh.bare_forearm:
                skin[v0:v1, u0:u1][ids == n_parts + 2 + 2 * k] = 128 + k + 1
        ids[ids > n_parts] = n_parts
        hand_rects.extend(rects)
        dirty.extend(rects)
        return boxes, box_ids, skin

    def _motion_blur(self, t: float, T: Pose, dirty: list[tuple[int, int, int, int]]) -> None:
        """Directional blur of each moving hand whose style asks for it: the hand's image velocity (its origin
        projected at t and t + 1/FPS, px/frame) sets a line kernel of length 0.7·‖v‖ (open shutter for 70 % of the
        frame); hand pixels and the background they smear over take the blurred colour."""
        n_parts = len(self._parts)
        intr = self._intr
        for wh in self.timeline.hands:
            hp = wh.path
            if not wh.motion_blur or not hp.t_start <= t <= hp.t_end:
                continue
            p0 = (T @ hp.state(t)[0]).t
            p1 = (T @ hp.state(t + 1.0 / FPS)[0]).t
            uv = intr.project(np.stack([p0, p1]))
            vel = uv[1] - uv[0]
            length = 0.7 * float(np.linalg.norm(vel))
            if length < 1.5 or not np.all(np.isfinite(vel)):
                continue
            ksz = int(np.ceil(length)) | 1
            kern = np.zeros((ksz, ksz), np.float32)
            c = ksz // 2
            d = vel / np.linalg.norm(vel) * (length / 2.0)
            cv2.line(kern, (int(round(c - d[0])), int(round(c - d[1]))), (int(round(c + d[0])), int(round(c + d[1]))),
                     1.0, 1)  # fmt: skip
            kern /= kern.sum()
            mask = (self._ids == n_parts).astype(np.float32)
            rows = np.flatnonzero(mask.any(axis=1))
            cols = np.flatnonzero(mask.any(axis=0))
            if len(rows) == 0:
                continue
            u0, v0 = max(0, int(cols[0]) - ksz), max(0, int(rows[0]) - ksz)
            u1, v1 = min(intr.width, int(cols[-1]) + ksz + 1), min(intr.height, int(rows[-1]) + ksz + 1)
            region = self._color[v0:v1, u0:u1]
            blurred = cv2.filter2D(region, -1, kern, borderType=cv2.BORDER_REPLICATE)
            spread = cv2.filter2D(mask[v0:v1, u0:u1], -1, kern, borderType=cv2.BORDER_CONSTANT) > 0.02
            region[spread] = blurred[spread]
            dirty.append((u0, v0, u1, v1))

    def _shadow(self, shapes: list[tuple[np.ndarray, float]], light: np.ndarray) -> tuple[int, int, int, int] | None:
        """Soft shadows on the table: each shape's sample points (camera frame) are projected along the light
        onto the table plane and into the image, filled as a convex polygon, blurred and multiplied in."""
        n, d = self._plane
        intr = self._intr
        denom = float(n @ light)
        if denom <= 1e-3:
            return None
        polys: list[tuple[np.ndarray, float]] = []
        for pts, dark in shapes:
            uv, hm = rz.shadow_polygon(pts, n, d, light, intr.fx, intr.fy, intr.cx, intr.cy)
            if hm > 0.35 or len(uv) == 0:
                continue
            polys.append((uv, dark * float(np.exp(-hm / 0.2))))
        if not polys:
            return None
        allp = np.concatenate([p for p, _ in polys])
        pad = 8
        u0 = max(0, int(np.floor(allp[:, 0].min())) - pad)
        v0 = max(0, int(np.floor(allp[:, 1].min())) - pad)
        u1 = min(intr.width, int(np.ceil(allp[:, 0].max())) + pad + 1)
        v1 = min(intr.height, int(np.ceil(allp[:, 1].max())) + pad + 1)
        if u0 >= u1 or v0 >= v1:
            return None
        step = 4
        mask = np.zeros(((v1 - v0) // step + 2, (u1 - u0) // step + 2), np.float32)
        for uv, strength in sorted(polys, key=lambda x: x[1]):
            hull = cv2.convexHull(np.round((uv - [u0, v0]) * (16.0 / step)).astype(np.int32))
            cv2.fillConvexPoly(mask, hull, float(strength), lineType=cv2.LINE_8, shift=4)
        mask = cv2.GaussianBlur(mask, (0, 0), 2.5 / step + 0.3)
        cu0, cv0, cu1, cv1 = rz.apply_shadow(self._color, self._ids, self._bg_table, mask, step, u0, v0, u1, v1)
        return (cu0, cv0, cu1, cv1) if cu0 < cu1 else None

    def _projector_shadow(self) -> np.ndarray | None:
        """The depth model's projector shadow of the clean depth just rendered, or None (a moving camera: the depth
        model computes it). With a fixed camera the clean depth equals the background's outside this frame's geometry
        rectangles (:attr:`_dirty`), so only their rows are computed; the rows the last frame computed and this one
        does not take the background's shadow again (the same mask as computed whole)."""
        if self._caster is not None:
            return None
        model, fx = self.options.depth_model, self._intr.fx
        if self._proj_bg is None:
            self._proj_bg = model.projector_shadow(self._bg.depth, fx)
            self._proj_shadow = self._proj_bg.copy()
        rows = np.zeros_like(self._proj_rows)
        for _u0, v0, _u1, v1 in self._dirty:
            rows[max(v0, 0) : max(v1, 0)] = True
        model.projector_shadow(self._depth, fx, out=self._proj_shadow, rows=(rows, self._proj_rows, self._proj_bg))
        self._proj_rows = rows
        return self._proj_shadow

    renders_into = True
    """:meth:`render` takes ``out`` buffers (the server's source process renders into its shared memory)."""

    def render(self, index: int, out: tuple[np.ndarray, np.ndarray] | None = None) -> Frame:
        """Frame ``index`` (0-based) with sensor noise and ground truth in ``meta["groundtruth"]``. ``out``: (colour
        uint8 H×W×3, depth float32 H×W) arrays the frame is written into (they become its ``color`` and ``depth``),
        else new ones."""
        if index < 0:
            raise ValueError(f"simulator: frame index must be >= 0, got {index}")
        color_out, depth_out = out if out is not None else (None, None)
        clean = self.render_clean(index)
        key = self.frame_key(index)
        depth = self.options.depth_model.apply(clean["depth"], clean["cosang"], key, fx=self._intr.fx, out=depth_out,
                                               shadow=self._projector_shadow())  # fmt: skip
        if self._blur_scratch is None:
            self._blur_scratch = np.empty_like(clean["color"])
        color = self.options.color_model.apply(clean["color"], key, clean["t"], self._phase, out=color_out,
                                               scratch=self._blur_scratch)  # fmt: skip
        n, d = clean["table_plane"]
        meta = {
            "groundtruth": {
                "poses": clean["poses"],
                "hand_box": clean["hand_box"],
                "visible": clean["visible"],
                "table_plane": {"normal": [float(x) for x in n], "offset": float(d)},
                "camera_pose": clean["camera_pose"],
            },
            "scenario": self.info.name,
            "seed": self.seed,
        }
        if self.timeline.hands:
            meta["groundtruth"]["hand_boxes"] = clean["hand_boxes"]
            meta["groundtruth"]["hand_box_ids"] = clean["hand_box_ids"]
            meta["groundtruth"]["skin_mask"] = clean["skin_mask"].copy()
        return Frame(index=index, timestamp=clean["t"], color=color, depth=depth, intrinsics=self._intr, meta=meta)


CLOTH_TINT = np.array([0.90, 1.0, 1.12], np.float32)
"""RGB tint of the table cloth of the hand scenarios (luma-preserving: 0.299·0.90 + 0.587 + 0.114·1.12 ≈ 0.98)."""


def table_cloth(color: np.ndarray) -> np.ndarray:
    """The colours (…×3, RGB 0..255) as a blue-grey cloth of the same brightness and texture. The hand scenarios
    use it because the wooden table has skin chrominance (measured Cr ≈ 150, Cb ≈ 104 in YCrCb, inside the skin
    cluster), which no chrominance skin model can separate from a hand; the cloth has Cr ≈ 121, Cb ≈ 137."""
    y = color[..., 0] * 0.299 + color[..., 1] * 0.587 + color[..., 2] * 0.114
    return np.clip(y[..., None] * CLOTH_TINT, 0.0, 255.0).astype(np.float32)


def _rect_array(rects: list[tuple[int, int, int, int]]) -> np.ndarray:
    """Rectangles ``(u0, v0, u1, v1)`` as an int64 array [n, 4] (for :func:`rasterizer.restore_rects`)."""
    return np.array(rects, np.int64).reshape(-1, 4)


def _stable(pose: Pose) -> Pose:
    """The pose with its quaternion at a fixed point of normalisation, so that writing it to JSON and reading
    it back (which normalises again) reproduces it bit for bit."""
    q = pose.q
    for _ in range(4):
        q2 = normalize_quat(q)
        if np.array_equal(q2, q):
            break
        q = q2
    return pose if q is pose.q else Pose(pose.t, q)


def box_corners(R: np.ndarray, t: np.ndarray, half: np.ndarray) -> np.ndarray:
    """The 8 corners [8, 3] of a box (rotation R, centre t, half extents half) in the parent frame."""
    return (_SIGNS * half) @ R.T + t


_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)


def _outside_area(pts: np.ndarray, intr: Intrinsics) -> float:
    """Area (px²) of the projected convex hull of camera-frame ``pts`` that falls outside the image."""
    z = pts[:, 2]
    if np.any(z <= 0.05):
        return 0.0
    uv = np.stack([intr.fx * pts[:, 0] / z + intr.cx, intr.fy * pts[:, 1] / z + intr.cy], axis=1)
    lo, hi = -0.5, np.array([intr.width - 0.5, intr.height - 0.5])
    if uv.min() >= lo and np.all(uv.max(axis=0) <= hi):
        return 0.0
    hull = cv2.convexHull(uv.astype(np.float32))
    total = float(cv2.contourArea(hull))
    img = np.array([[lo, lo], [hi[0], lo], [hi[0], hi[1]], [lo, hi[1]]], np.float32)
    inter, _ = cv2.intersectConvexConvex(hull, img)
    return max(0.0, total - float(inter))
