"""The viser 3D scene: table, depth point cloud, parts at their estimated poses, particle clouds, words, ghost, hands.

World frame = the table frame (y up along the table normal; see the README's conventions). Everything
the camera measures lives under the node ``/camera`` whose pose is the camera in the table frame, so
parts, particles and the depth cloud are set in camera coordinates as they come out of the pipeline.
Handles are created once and updated in place; updates run on their own thread (latest snapshot only),
so the pipeline worker never waits for the browser.

Cost in the browser: every scene message makes viser's client redraw for a short while (its "settle" window,
about 0.25 s), and a browser without a GPU draws in software on the CPU the server needs. So the scene sends
little: at most :data:`SCENE_HZ` updates per second, only the nodes that moved visibly (a part's box and
particles when the part moved by :data:`POSE_STEP_M` or :data:`POSE_STEP_DEG`, the depth cloud when the depth
image changed), nothing at all while nothing moves; the lights cast no shadows (three extra shadow passes
per frame) and no environment map (image-based lighting: ~0.5 s of CPU per frame in a software renderer,
against ~15 ms for the whole scene without it), and the client redraws at most :data:`SCENE_RENDER_FPS` times
per second unless the user is turning the view.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import numpy as np

from tracker.frame import Frame
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.os_names import name_os_thread
from tracker.snapshot import Snapshot

log = logging.getLogger(__name__)

DEPTH_POINTS = 1200
"""About this many depth pixels (a regular subsample) make the point cloud (viser's native points). A browser
drawing in software spends about 9 µs per point and frame: 3000 points made a frame of the scene cost ~35 ms
of CPU, 1200 points ~15 ms (benchmarks/bench_server.py's machine)."""
DEPTH_EVERY = 3
"""The depth cloud is refreshed on every this-many scene updates at most (the table hardly changes)..."""
DEPTH_CHANGE_M = 0.005
"""...and only when at least :data:`DEPTH_CHANGED_SHARE` of its points moved by more than this (metres) or
appeared or vanished since the cloud shown (sensor noise alone does not redraw the scene)."""
DEPTH_CHANGED_SHARE = 0.01
MAX_PARTICLES_SHOWN = 100
"""Particles per part sent to the browser (a random but fixed subset)."""
POSE_STEP_M = 0.0005
"""A part's box (and its particles) is moved in the scene when its estimate moved by more than this (metres)..."""
POSE_STEP_DEG = 0.25
"""...or turned by more than this (degrees) since the pose shown; smaller changes are not visible at the
scene's scale (a 36 mm cube about 0.3 m away) and would only make the browser redraw."""
SCENE_HZ = 4.0
"""Scene updates per second at most (``Settings.scene_hz``). The embedded scene shares the page's main thread
(same site): a browser drawing it in software (no GPU) at 10 Hz starved the panel (0.07 panel fps against 1.8
processed under heavy load); at 4 Hz and half resolution the panel showed every processed frame
(benchmarks/bench_server.py)."""
SCENE_RENDER_FPS = 8.0
"""The browser redraws the scene at most this many times per second (``Settings.scene_render_fps``; 0: as
often as viser's client wants, up to the display's rate) except while the user turns, pans or zooms the view
(and for a second after), when it draws at the display's rate. Twice :data:`SCENE_HZ`: each update is drawn
(viser's client redraws for ~0.25 s after a message)."""
CAMERA_PATH_POINTS = 900
"""Camera positions kept for the camera path (30 s at 30 fps)."""
MAX_HANDS_SHOWN = 2
"""Tracked hands drawn (a translucent skin-coloured sphere at each hand's position, labelled with what it holds)."""
HAND_RADIUS = 0.04
"""Metres: radius of a hand's sphere (about half a palm's length)."""


def _wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    q = np.asarray(q_xyzw, dtype=float)
    return np.array([q[3], q[0], q[1], q[2]])


def _pose_from_any(d: Any) -> Pose | None:
    if isinstance(d, Pose):
        return d
    if isinstance(d, dict) and "t" in d and "q" in d:
        try:
            return Pose.from_dict(d)
        except (ValueError, TypeError, KeyError):
            return None
    return None


def word_labels(mode_state: dict[str, Any]) -> dict[str, str]:
    """``{part: word}`` from a learning-mode state (keys ``words`` or ``assignment``)."""
    for key in ("words", "assignment", "word_of_part"):
        value = mode_state.get(key)
        if isinstance(value, dict):
            return {str(k): str(v) for k, v in value.items() if isinstance(v, str | int | float)}
    return {}


def ghost_target(mode_state: dict[str, Any]) -> tuple[str, Pose] | None:
    """``(part, camera-frame pose)`` of the next step's target in a guidance-mode state, if any."""
    step = mode_state.get("next_step")
    if not isinstance(step, dict) or not step.get("part"):
        return None
    pose = _pose_from_any(step.get("target_pose"))
    return None if pose is None else (str(step["part"]), pose)


def _moved(shown: Pose | None, pose: Pose) -> bool:
    """Whether ``pose`` differs visibly from the ``shown`` one (see :data:`POSE_STEP_M`, :data:`POSE_STEP_DEG`)."""
    if shown is None:
        return True
    if float(np.linalg.norm(np.asarray(pose.t) - np.asarray(shown.t))) > POSE_STEP_M:
        return True
    dot = abs(float(np.dot(np.asarray(pose.q, float), np.asarray(shown.q, float))))
    return float(np.degrees(2.0 * np.arccos(min(1.0, dot)))) > POSE_STEP_DEG


def render_cap_js(fps: float) -> str:
    """JavaScript for viser's client: its redraws (``requestAnimationFrame`` callbacks) at most ``fps`` per second,
    except for a second after the user pressed, dragged, scrolled or typed in the scene (the view then follows at
    the display's rate). Installs once per page; ``window.__sceneRenderCap`` tells the cap in force."""
    gap_ms = 1000.0 / float(fps)
    return f"""(() => {{
  if (window.__sceneRenderCap) return;
  window.__sceneRenderCap = {float(fps)};
  const raf = window.requestAnimationFrame.bind(window), caf = window.cancelAnimationFrame.bind(window);
  const gap = {gap_ms:.3f};
  let last = -1e9, lastFrame = null, touched = -1e9, next = 1;
  const waiting = new Map();  // our id -> [kind, handle] of the callback's pending timer or frame
  const touch = (ev) => {{ if (ev.type !== "pointermove" || ev.buttons) touched = performance.now(); }};
  for (const type of ["pointerdown", "pointermove", "wheel", "keydown", "touchmove"]) {{
    window.addEventListener(type, touch, {{ capture: true, passive: true }});
  }}
  window.requestAnimationFrame = (cb) => {{
    const id = next++;
    const run = (t) => {{
      const now = performance.now();
      const wait = gap - (now - last);
      if (t !== lastFrame && wait > 1 && now - touched > 1000) {{
        waiting.set(id, ["timer", setTimeout(() => waiting.set(id, ["frame", raf(run)]), wait)]);
        return;
      }}
      waiting.delete(id);
      if (t !== lastFrame) {{ lastFrame = t; last = now; }}  // the callbacks of one frame all run in it
      cb(t);
    }};
    waiting.set(id, ["frame", raf(run)]);
    return id;
  }};
  window.cancelAnimationFrame = (id) => {{
    const w = waiting.get(id);
    if (!w) return;
    waiting.delete(id);
    if (w[0] === "timer") clearTimeout(w[1]); else caf(w[1]);
  }};
}})();"""


class Scene:
    """A viser server showing the pipeline's snapshots."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8080,
        parts: list[PartSpec] | None = None,
        render_fps: float = SCENE_RENDER_FPS,
    ) -> None:
        import viser

        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.render_fps = float(render_fps)
        if self.render_fps > 0:
            self._run_in_viewers(render_cap_js(self.render_fps))
        self.port = self.server.get_port()
        self.server.gui.configure_theme(control_width="small", show_logo=False, show_share_button=False)
        try:
            self.server.gui.main_panel.minimize()  # the scene is the point; the panel opens on click
        except AttributeError:
            pass
        self.server.initial_camera.position = (0.0, 0.26, 0.32)  # above and in front of the table (user side)
        self.server.initial_camera.look_at = (0.0, 0.0, 0.0)
        self.server.initial_camera.up = (0.0, 1.0, 0.0)
        sc = self.server.scene
        sc.configure_default_lights(enabled=True, cast_shadow=False)  # shadows: 3 more passes for every frame
        sc.configure_environment_map(hdri=None)  # lit by the two default lights only (see the module docstring)
        sc.set_up_direction("+y")
        sc.add_grid(
            "/table",
            width=1.0,
            height=1.0,
            plane="xz",
            cell_size=0.05,
            section_size=0.25,
            plane_color=(225, 215, 195),
            plane_opacity=0.6,
        )
        self.camera_node = sc.add_frame("/camera", show_axes=True, axes_length=0.05, axes_radius=0.003)
        self.depth_cloud = sc.add_point_cloud(
            "/camera/depth", np.zeros((1, 3), np.float32), (128, 128, 128), point_size=0.003
        )
        # camera odometry: the camera's frustum (under /camera) and its path in the table frame
        self.frustum = sc.add_camera_frustum("/camera/frustum", fov=np.radians(49.0), aspect=4.0 / 3.0, scale=0.04,
                                             color=(40, 110, 220), visible=False)
        self.camera_path = sc.add_point_cloud("/camera_path", np.zeros((1, 3), np.float32), (40, 110, 220),
                                              point_size=0.003, precision="float32", visible=False)
        self._path: list[np.ndarray] = []
        self.ghost = sc.add_box(
            "/camera/ghost", color=(255, 255, 255), dimensions=(0.036,) * 3, opacity=0.35, visible=False
        )
        self.hand_nodes = [
            sc.add_icosphere(f"/camera/hands/{i}", radius=HAND_RADIUS, color=(224, 172, 140), subdivisions=2,
                             opacity=0.5, visible=False)
            for i in range(MAX_HANDS_SHOWN)
        ]
        self.hand_labels = [sc.add_label(f"/camera/hands/{i}/text", "", position=(0.0, -0.05, 0.0), visible=False)
                            for i in range(MAX_HANDS_SHOWN)]  # fmt: skip
        self.parts: list[PartSpec] = []
        self.part_nodes: dict[str, Any] = {}
        self.particle_nodes: dict[str, Any] = {}
        self.label_nodes: dict[str, Any] = {}
        self._particle_idx: dict[str, np.ndarray] = {}
        self._shown_poses: dict[str, Pose] = {}  # the pose each part's box shows
        self._shown_depth: np.ndarray | None = None  # the subsampled depth image the cloud shows (metres)
        self._rng = np.random.default_rng(0)
        self._frames = 0
        if parts:
            self.set_parts(parts)

    def set_parts(self, parts: list[PartSpec]) -> None:
        """Create one box (or mesh), particle cloud and word label per part (replacing earlier ones)."""
        if [p.name for p in parts] == [p.name for p in self.parts]:
            return
        # children first: removing a part's node removes its word label with it in viser
        for handles in (self.label_nodes, self.part_nodes, self.particle_nodes):
            for h in handles.values():
                h.remove()
            handles.clear()
        sc = self.server.scene
        self.parts = list(parts)
        self._shown_poses.clear()
        for p in parts:
            color = p.color or (180, 180, 180)
            if p.box is not None:
                node = sc.add_box(f"/camera/parts/{p.name}", color=color, dimensions=p.box, visible=False)
            else:
                mesh = p.load_mesh()
                node = sc.add_mesh_simple(
                    f"/camera/parts/{p.name}", mesh.vertices, mesh.faces, color=color, visible=False
                )
            self.part_nodes[p.name] = node
            self.particle_nodes[p.name] = sc.add_point_cloud(
                f"/camera/particles/{p.name}",
                np.zeros((1, 3), np.float32),
                color,
                point_size=0.002,
                precision="float32",
                visible=False,
            )
            self.label_nodes[p.name] = sc.add_label(
                f"/camera/parts/{p.name}/word", "", position=(0.0, -0.03, 0.0), visible=False
            )

    def update(self, snap: Snapshot, frame: Frame | None) -> None:
        """Move every handle to the snapshot's state (one batched message)."""
        self._frames += 1
        with self.server.atomic():
            if snap.table is not None:
                cam_in_table = Pose.from_dict(snap.table["table_to_camera"]).inverse()
                self.camera_node.wxyz = _wxyz(cam_in_table.q)
                self.camera_node.position = cam_in_table.t
                if snap.camera_pose is not None:  # odometry on: show the frustum and where the camera went
                    self._path = (self._path + [cam_in_table.t.astype(np.float32)])[-CAMERA_PATH_POINTS:]
                    self.camera_path.points = np.stack(self._path)
                    self.camera_path.visible = True
                    if frame is not None:
                        self.frustum.fov = float(2.0 * np.arctan2(frame.intrinsics.height / 2.0, frame.intrinsics.fy))
                        self.frustum.aspect = frame.intrinsics.width / frame.intrinsics.height
                    self.frustum.color = (40, 110, 220) if snap.camera_pose_ok else (230, 120, 30)
                    self.frustum.visible = True
            if frame is not None and frame.depth is not None and self._frames % DEPTH_EVERY == 1:
                self._update_depth(frame)
            words = word_labels(snap.mode_state) if snap.mode == "learning" else {}
            for name, node in self.part_nodes.items():
                pose = snap.poses.get(name)
                moved = pose is not None and _moved(self._shown_poses.get(name), pose)
                if moved:
                    node.wxyz = _wxyz(pose.q)
                    node.position = pose.t
                    node.visible = True
                    self._shown_poses[name] = pose
                cloud = snap.particles.get(name)
                pnode = self.particle_nodes[name]
                if moved and cloud is not None and len(cloud):  # the particles go with the box
                    idx = self._particle_idx.get(name)
                    if idx is None or idx.max(initial=-1) >= len(cloud) or len(idx) > len(cloud):
                        n = min(MAX_PARTICLES_SHOWN, len(cloud))
                        idx = np.sort(self._rng.choice(len(cloud), n, replace=False))
                        self._particle_idx[name] = idx
                    pnode.points = np.ascontiguousarray(cloud[idx], dtype=np.float32)
                    pnode.visible = True
                label = self.label_nodes[name]
                word = words.get(name)
                if word:
                    if label.text != word:
                        label.text = word
                    label.visible = True
                elif label.visible:
                    label.visible = False
            self._update_hands(snap.hands)
            ghost = ghost_target(snap.mode_state) if snap.mode == "guidance" else None
            if ghost is not None:
                part, pose = ghost
                self.ghost.wxyz = _wxyz(pose.q)
                self.ghost.position = pose.t
                spec = next((p for p in self.parts if p.name == part), None)
                if spec is not None and spec.color is not None:
                    self.ghost.color = spec.color
                self.ghost.visible = True
            elif self.ghost.visible:
                self.ghost.visible = False

    def _update_depth(self, frame: Frame) -> None:
        """The depth cloud from a regular subsample of ``frame``'s depth, when it changed visibly."""
        h, w = frame.depth.shape
        k = max(1, int(round(np.sqrt(h * w / DEPTH_POINTS))))
        d = np.asarray(frame.depth[::k, ::k], dtype=np.float32)
        ok = np.isfinite(d) & (d > 0)
        shown = self._shown_depth
        if shown is not None and shown.shape == d.shape:
            was = np.isfinite(shown) & (shown > 0)
            with np.errstate(invalid="ignore"):
                changed = (ok != was) | (ok & was & (np.abs(d - shown) > DEPTH_CHANGE_M))
            if changed.mean() < DEPTH_CHANGED_SHARE:
                return
        if not ok.any():
            return
        v, u = np.mgrid[0:h:k, 0:w:k]
        pts = frame.intrinsics.backproject(u[ok], v[ok], d[ok])
        self.depth_cloud.points = pts.astype(np.float32)
        self.depth_cloud.colors = frame.color[::k, ::k][ok]
        self._shown_depth = d

    def _run_in_viewers(self, source: str) -> None:
        """Run JavaScript in every viewer, present and future (viser keeps the message for new clients)."""
        try:
            from viser import _messages

            self.server._websock_server.queue_message(_messages.RunJavascriptMessage(source=source))
        except (ImportError, AttributeError) as exc:  # another viser version: the scene works, uncapped
            log.warning("cannot cap the scene's redraw rate in this viser version: %s", exc)

    def _update_hands(self, hands: list[dict[str, Any]]) -> None:
        """A sphere per tracked hand with a 3-D position (camera frame), labelled "holding the red cube" etc."""
        placed = [h for h in hands if h.get("position") is not None][:MAX_HANDS_SHOWN]
        for i, (node, label) in enumerate(zip(self.hand_nodes, self.hand_labels, strict=True)):
            if i >= len(placed):
                if node.visible:
                    node.visible = label.visible = False
                continue
            node.position = np.asarray(placed[i]["position"], float)
            node.visible = True
            text = str(placed[i].get("text") or "")
            if label.text != text:
                label.text = text
            label.visible = bool(text)

    def stop(self) -> None:
        self.server.stop()


class SceneUpdater:
    """Feeds the newest snapshot of a worker to a :class:`Scene` from its own thread, at most ``max_hz``."""

    def __init__(self, scene: Scene, worker, max_hz: float = SCENE_HZ) -> None:
        self.scene = scene
        self.worker = worker
        self.max_hz = max_hz
        self._event = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="viser-scene", daemon=True)
        worker.add_listener(self._on_snapshot)

    def _on_snapshot(self, _snap: Snapshot) -> None:
        self._event.set()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._event.set()
        self.worker.remove_listener(self._on_snapshot)
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        name_os_thread()
        last_version = -1
        while not self._stop.is_set():
            self._event.wait(timeout=1.0)
            self._event.clear()
            version, snap, frame = self.worker.published
            if snap is None or version == last_version:
                continue
            if not self.scene.server.get_clients() and version - last_version < 30 and last_version >= 0:
                continue  # nobody watching: refresh rarely
            last_version = version
            pipeline = self.worker.pipeline
            t0 = time.perf_counter()
            try:
                if pipeline is not None:
                    self.scene.set_parts(pipeline.parts)
                self.scene.update(snap, frame)
            except Exception as exc:  # noqa: BLE001 - the scene must not take the server down
                log.warning("viser scene update failed: %s", exc)
            rest = 1.0 / self.max_hz - (time.perf_counter() - t0)
            if rest > 0:
                self._stop.wait(rest)
