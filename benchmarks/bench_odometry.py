"""Benchmark of the camera odometry (issue 15): ATE / rotation / RPE on held-out simulated sessions with a moving
camera, the default dense odometry against the seed's FastSLAM option and OpenCV's RGB-D odometry (baseline).

Sessions: simulator seeds >= 100 only (the odometry was tuned on seeds 0–4), 300 frames (10 s) each: ``static``
(no hand) and ``guess-1`` (a hand picks up and moves parts), camera ``handheld`` (sway + jitter) and ``sway``.
World frame = the first frame's camera frame; no trajectory alignment. ATE = RMSE of the camera position, rotation
RMSE, RPE = RMSE of the relative translation error over 1 s, per second. Every method gets the simulator's hand
box as its exclusion mask (``--mask hand`` of the CLI); OpenCV's odometry gets it as its frame mask.

Also run: the external castle-simu sequence (ViSP, 40 frames, moving camera around a static object, exact
ground truth; only the object has depth, no table), where the camera's motion is the inverse of the object's
ground-truth motion. ``real/tum-desk`` holds one frame only, so it has no motion to estimate.

Timing: CPU time of the odometry step per frame (``time.thread_time``, the main thread; OpenCV may use more
threads) and wall time, median / p95. Writes benchmarks/results/odometry.json, odometry.md and trajectory plots
odometry_<scenario>_<motion>_<seed>.png. Usage::

    NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/bench_odometry.py [--frames 300] [--quick]
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.odometry_baseline import OpenCvOdometry  # noqa: E402
from tracker.evaluation.machine_info import machine_info  # noqa: E402
from tracker.evaluation.trajectory_errors import trajectory_errors  # noqa: E402
from tracker.geometry.pose import Pose  # noqa: E402
from tracker.odometry import OdometryConfig, make_odometry  # noqa: E402
from tracker.odometry.exclusion_mask import exclusion_mask  # noqa: E402
from tracker.shared_data import shared_root  # noqa: E402
from tracker.sources.simulator import SimOptions, SimulatedTable  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SHARED = shared_root()
METHODS = ("default", "fastslam", "opencv-rgb")
IN_TRACKER = "in-tracker"
PARTS = "parts"
FUSED = "fused"
"""The dense odometry and the resting parts checking each other (:mod:`tracker.odometry.fused_odometry`): the dense
odometry with the simulator's hand box as mask, and the tracker of ``track`` (odometry off) for the landmarks; CPU
time is the dense step plus the fusion (the tracker runs anyway)."""
"""The camera pose from the tracked parts that stay put (:mod:`tracker.odometry.part_landmarks`), the tracker of
``track`` (default preset, odometry off) running on the frames; CPU time is the landmark step's alone."""
"""The default odometry run inside the tracker (``track --odometry default``: its own mask of foreground, hand/arm
boxes and moving parts from the tracker's estimates; no simulator hand box); its camera poses are scored."""
SESSIONS = (("static", "handheld", 100), ("guess-1", "handheld", 100), ("static", "handheld", 101),
            ("guess-1", "handheld", 101), ("static", "sway", 102), ("guess-1", "sway", 102))


def _odometry(method: str, intrinsics):
    if method == "opencv-rgb":
        return OpenCvOdometry(intrinsics, "rgb")
    return make_odometry(method, intrinsics, seed=0)


def _run_frames(method: str, intrinsics, frames, masks) -> dict:
    odo = _odometry(method, intrinsics)
    est, cpu, wall, ok = [], [], [], []
    for f, m in zip(frames(), masks(), strict=True):
        c0, w0 = time.thread_time(), time.perf_counter()
        r = odo.step(f, m)
        cpu.append(1e3 * (time.thread_time() - c0))
        wall.append(1e3 * (time.perf_counter() - w0))
        est.append(r.pose_world_camera)
        ok.append(bool(r.ok))
    return {"est": est, "cpu": cpu, "wall": wall, "ok": ok}


def _summary(run: dict, times, truth) -> dict:
    e = trajectory_errors(np.asarray(times), run["est"], truth, delta=1.0).to_dict()
    cpu, wall = np.asarray(run["cpu"][1:]), np.asarray(run["wall"][1:])
    e.update(cpu_ms_median=round(float(np.median(cpu)), 1), cpu_ms_p95=round(float(np.percentile(cpu, 95)), 1),
             wall_ms_median=round(float(np.median(wall)), 1), wall_ms_p95=round(float(np.percentile(wall, 95)), 1),
             measured=int(sum(run["ok"])), poses=len(run["est"]))
    return e


def _run_in_tracker(src, frames) -> dict:
    """The tracker of ``track --odometry default`` on the frames; its odometry stage's camera poses and CPU time."""
    from app.commands.track import TrackSession
    from tracker.filter.tracker_config import TrackerConfig

    session = TrackSession(src.parts, src.intrinsics, src.initial_poses, TrackerConfig.preset("default"), seed=0,
                           odometry="default")
    est, cpu, wall, ok = [], [], [], []
    for f in frames():
        w0 = time.perf_counter()
        session.step(f)
        cpu.append(1e3 * session.last_ego_cpu)
        wall.append(1e3 * (time.perf_counter() - w0))
        est.append(session.ego_step.pose_world_camera)
        ok.append(bool(session.ego_step.ok))
    return {"est": est, "cpu": cpu, "wall": wall, "ok": ok, "jumps": session.ego.jumps}


def _run_parts(src, frames) -> dict:
    """The tracker of ``track`` (odometry off) on the frames; the camera poses its resting parts give."""
    from app.commands.track import TrackSession
    from tracker.filter.tracker_config import TrackerConfig
    from tracker.odometry.part_landmarks import PartLandmarkOdometry

    session = TrackSession(src.parts, src.intrinsics, src.initial_poses, TrackerConfig.preset("default"), seed=0)
    trk = session.tracker
    corners = {name: trk.corners[i] for i, name in enumerate(trk.names)}
    odo = PartLandmarkOdometry()
    est, cpu, wall, ok = [], [], [], []
    for f in frames():
        session.step(f)
        c0, w0 = time.thread_time(), time.perf_counter()
        est.append(odo.update(trk.landmark_poses, corners))
        cpu.append(1e3 * (time.thread_time() - c0))
        wall.append(1e3 * (time.perf_counter() - w0))
        ok.append(odo.used > 0)
    return {"est": est, "cpu": cpu, "wall": wall, "ok": ok}


def _run_fused(src, frames, masks) -> dict:
    """The dense odometry and the tracker of ``track`` (odometry off) on the frames, fused."""
    from app.commands.track import TrackSession
    from tracker.filter.tracker_config import TrackerConfig
    from tracker.odometry.fused_odometry import FusedOdometry

    session = TrackSession(src.parts, src.intrinsics, src.initial_poses, TrackerConfig.preset("default"), seed=0)
    trk = session.tracker
    corners = {name: trk.corners[i] for i, name in enumerate(trk.names)}
    dense = make_odometry("default", src.intrinsics, seed=0, config=OdometryConfig.fast())
    fused = FusedOdometry()
    est, cpu, wall, ok = [], [], [], []
    for f, m in zip(frames(), masks(), strict=True):
        c0, w0 = time.thread_time(), time.perf_counter()
        r = dense.step(f, m, prior=fused.dense_prior(float(f.timestamp)))  # start from the fused path
        c1, w1 = time.thread_time(), time.perf_counter()
        session.step(f)
        c2, w2 = time.thread_time(), time.perf_counter()
        lm = trk.landmark_poses
        fused.predict(float(f.timestamp), r.pose_world_camera if r.ok else None, lm, corners)
        table = None if session.table is None else (session.table.normal, session.table.offset)
        plane = fused.measure_table(f.depth, src.intrinsics, m, guess=table) if f.depth is not None else None
        step = fused.correct(lm, corners, plane)
        cpu.append(1e3 * (c1 - c0 + time.thread_time() - c2))
        wall.append(1e3 * (w1 - w0 + time.perf_counter() - w2))
        est.append(step.pose)
        ok.append(step.source != "hold")
    return {"est": est, "cpu": cpu, "wall": wall, "ok": ok,
            "checks": f"{fused.dense_rejected} dense rejected, {fused.dense_overridden} overridden, "
                      f"{fused.parts_rejected} part consensus rejected"}


def _run_methods(label: str, intrinsics, frames, masks, times, truth, methods=METHODS, src=None) -> tuple[dict, dict]:
    """Every method on the same frames: per-method summaries and estimated trajectories (with the truth)."""
    out, trajs = {}, {"truth": truth}
    for method in methods:
        if method in (IN_TRACKER, PARTS, FUSED):
            if src is None:
                continue
            run = (_run_in_tracker(src, frames) if method == IN_TRACKER else _run_parts(src, frames)
                   if method == PARTS else _run_fused(src, frames, masks))
        else:
            run = _run_frames(method, intrinsics, frames, masks)
        out[method] = _summary(run, times, truth)
        if "jumps" in run:
            out[method]["jumps"] = run["jumps"]
        if "checks" in run:
            out[method]["checks"] = run["checks"]
        trajs[method] = run["est"]
        print(f"  {label} {method}: {json.dumps(out[method])}", flush=True)
    return out, trajs


def _extent(truth: list[Pose]) -> dict:
    shift = max(float(np.linalg.norm(t.t)) for t in truth)
    turn = max(float(np.degrees(Pose().rotation_error(t))) for t in truth)
    return {"camera_max_shift_mm": round(1e3 * shift, 1), "camera_max_turn_deg": round(turn, 2)}


def simulated_session(scenario: str, motion: str, seed: int, n: int, methods=METHODS) -> tuple[dict, dict]:
    src = SimulatedTable(scenario, seed=seed, options=SimOptions(camera_motion=motion), n_frames=n)
    w0 = src.camera_pose_at(0).inverse()
    truth = [w0 @ src.camera_pose_at(i) for i in range(n)]
    times = [i / 30.0 for i in range(n)]
    boxes = [src.render_clean(i)["hand_box"] for i in range(n)]
    shape = (src.intrinsics.height, src.intrinsics.width)

    def frames():
        return (src.render(i) for i in range(n))

    def masks():
        return (exclusion_mask(shape, b) if b is not None else None for b in boxes)

    out, trajs = _run_methods(f"{scenario}/{motion}/seed {seed}", src.intrinsics, frames, masks, times, truth,
                              methods, src)
    hand = sum(b is not None for b in boxes)
    return {"scenario": scenario, "motion": motion, "seed": seed, "frames": n, **_extent(truth),
            "frames_with_hand": hand, "methods": out}, trajs


def castle_session() -> tuple[dict, dict] | None:
    from tracker.sources.recording import RecordingSource

    root = SHARED / "data" / "external" / "castle-simu"
    if not root.is_dir():
        return None
    src = RecordingSource(root)
    n = len(src)
    obj = [src.groundtruth(i)["castle"] for i in range(n)]  # object pose in each camera frame
    truth = [obj[0] @ o.inverse() for o in obj]  # camera i in the first camera's frame
    times = [src.timestamp(i) for i in range(n)]

    def frames():
        return (src.read(i) for i in range(n))

    def masks():
        return (None for _ in range(n))

    out, trajs = _run_methods("castle-simu", src.intrinsics, frames, masks, times, truth)
    return {"scenario": "castle-simu (external)", "motion": "ViSP", "seed": None, "frames": n, **_extent(truth),
            "frames_with_hand": 0, "methods": out}, trajs


def plot(name: str, trajs: dict, title: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    colours = {"truth": "k", "default": "tab:blue", "fastslam": "tab:orange", "opencv-rgb": "tab:green",
               IN_TRACKER: "tab:purple", PARTS: "tab:red",
               FUSED: "tab:brown"}
    n = len(trajs["truth"])
    tt = np.arange(n) / 30.0
    for key, poses in trajs.items():
        p = 1e3 * np.array([q.t for q in poses])
        style = {"color": colours[key], "lw": 2.0 if key == "truth" else 1.2, "label": key}
        axes[0].plot(p[:, 0], p[:, 2], **style)
        if key != "truth":
            err = [1e3 * a.translation_error(b) for a, b in zip(poses, trajs["truth"], strict=True)]
            axes[1].plot(tt, err, **style)
            axes[2].plot(tt, np.degrees([a.rotation_error(b) for a, b in zip(poses, trajs["truth"], strict=True)]),
                         **style)
    axes[0].set(xlabel="x (mm)", ylabel="z (mm)", title="camera path, top view (first camera frame)")
    axes[0].axis("equal")
    axes[1].set(xlabel="time (s)", ylabel="position error (mm)", yscale="log", title="position error",
                ylim=(0.01, None))
    axes[2].set(xlabel="time (s)", ylabel="rotation error (°)", yscale="log", title="rotation error",
                ylim=(0.001, None))
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    path = RESULTS / f"odometry_{name}.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path.name


def markdown(res: dict) -> str:
    m = res["machine"]
    in_tracker = any(IN_TRACKER in s["methods"] for s in res["sessions"])
    parts = any(PARTS in s["methods"] for s in res["sessions"])
    fused = any(FUSED in s["methods"] for s in res["sessions"])
    title = ("## Camera odometry inside the tracker (issue 15)" if in_tracker else
             "## Dense odometry and resting parts fused (issue 15)" if fused else
             "## Camera pose from the tracked parts (issue 15)" if parts else "## Camera odometry (issue 15)")
    lines = [
        title,
        "",
        f"Machine: {m['nproc']} cores, {m['cpu']}, Python {m['python']}; NUMBA_NUM_THREADS=1. 1-minute load "
        f"{m['load_1min_at_start']} at the start and {res['load_1min_at_end']} at the end: taken under load (the "
        "2 cores were shared with other agents' jobs), so wall times are pessimistic; CPU times are of the main "
        "thread.",
        "",
        "Held-out simulator seeds (100–102, never tuned on), 300 frames each, 640×480, world = first camera frame, "
        "no trajectory alignment; every method masks the simulator's hand box. `default` = dense frame-to-keyframe "
        "RGB-D odometry (`tracker/odometry/camera_odometry.py`), `fastslam` = the seed's AKAZE + FastSLAM 1.0 "
        "(100 particles), `opencv-rgb` = the baseline, OpenCV 5's `cv2.Odometry` (photometric, frame to frame, "
        "its samples' usage; its RGB_DEPTH and DEPTH variants diverged on these scenes, see notes). ATE = RMSE of the "
        "camera position; RPE over 1 s, per second. Ratio = baseline ATE / default ATE."
        + (f" `{IN_TRACKER}` = the same dense odometry run by the tracker (`track --odometry default`, "
           "`tracker/odometry/ego_motion.py`) with its own mask and no simulator hand box: foreground above the "
           "propagated table plane except the silhouettes of the parts it tracks as static, the whole bounding box "
           "of hand/arm-sized foreground blobs (with their shadows), the silhouettes of moving parts; its CPU time "
           "is the whole odometry stage (mask + odometry). `jumps`: registrations rejected as a jump of over 8 mm / "
           "1.5° between frames (the tracker is then re-anchored instead of being moved)." if in_tracker else "")
        + (f" `{PARTS}` = the camera pose from the tracked parts that stay put (`tracker/odometry/part_landmarks.py`):"
           " the tracker of `track` (default preset, odometry off, no simulator hand box) runs on the frames; the "
           "parts it sees well and refines are landmarks at their first world pose, the camera pose is the consensus "
           "of the landmarks (a part a hand moves is outvoted and re-adopted when it rests again); its CPU time is "
           "the landmark step alone (the tracker runs anyway). `measured`: frames with an agreeing landmark."
           if parts else "")
        + (f" `{FUSED}` = the dense odometry and the resting parts checking each other "
           "(`tracker/odometry/fused_odometry.py`): the dense pose is the prior; a dense step that leaves the "
           "constant-velocity prediction by over 2 mm / 0.3° is taken only when the resting parts fit it better; the "
           "table plane, measured in each frame near where the pose puts it, fixes the tilt and the height; the parts "
           "that agree with the prior (6 mm) correct its translation along the table and, with ≥ 3 of them, its turn "
           "about the table's normal beyond 0.1°; a disagreeing consensus of ≥ 3 parts overrules it, a smaller one "
           "is ignored. Its CPU time is the dense step plus the fusion and the plane fit (the tracker runs anyway); "
           "`measured`: frames not held on the prediction." if fused else ""),
        "",
        "| session | camera moved mm / ° | hand frames | method | ATE RMSE mm (max) | rot RMSE ° | RPE mm/s | "
        "RPE °/s | measured | CPU ms median / p95 | wall ms median / p95 |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in res["sessions"]:
        name = f"{s['scenario']} {s['motion']}" + (f" seed {s['seed']}" if s["seed"] is not None else "")
        for method, e in s["methods"].items():
            label = method + (f" ({e['jumps']} jumps)" if "jumps" in e else "") + (
                f" ({e['checks']})" if "checks" in e else "")
            lines.append(
                f"| {name} | {s['camera_max_shift_mm']:.0f} / {s['camera_max_turn_deg']:.1f} | {s['frames_with_hand']} "
                f"| {label} | {e['ate_rmse_mm']:.2f} ({e['ate_max_mm']:.1f}) | {e['rot_rmse_deg']:.3f} | "
                f"{e['rpe_mm_per_s']:.2f} | {e['rpe_deg_per_s']:.3f} | {e['measured']}/{e['poses']} | "
                f"{e['cpu_ms_median']:.1f} / {e['cpu_ms_p95']:.1f} | "
                f"{e['wall_ms_median']:.1f} / {e['wall_ms_p95']:.1f} |"
            )
            name = ""
    ratios = []
    others = [m for m in res["sessions"][0]["methods"] if m != "default"] if res["sessions"] else []
    for s in res["sessions"]:
        ate = {k: v["ate_rmse_mm"] for k, v in s["methods"].items()}
        base = max(ate["default"], 1e-6)
        label = f"{s['scenario']} {s['motion']}" + ("" if s["seed"] is None else f" {s['seed']}")
        ratios.append(f"{label}: " + " / ".join(f"{ate[m] / base:.2g}×" for m in others if m in ate))
    lines += ["", f"Ratios ({' / '.join(others)} ATE over the default's) per session: " + "; ".join(ratios) + ".", ""]
    lines += ["Trajectory plots (top view, position and rotation error over time): "
              + ", ".join(f"`benchmarks/results/{p}`" for p in res["plots"]), "", res["notes"], ""]
    return "\n".join(lines)


NOTES = (
    "Notes. Targets of issue 15 on unseen hand-held sessions of 300 frames: ATE RMSE <= 3 mm, rotation RMSE <= 0.3°, "
    "RPE <= 3 mm/s, a pose for every frame, >= 30 fps. Every method returns a pose for every frame (`measured` counts "
    "the frames whose pose was measured rather than extrapolated or held). OpenCV's `cv2.Odometry` with "
    "`OdometryType_RGB_DEPTH` or `DEPTH` (ICP) diverged on these table scenes already between neighbouring frames "
    "(translations of 10–15 cm along the table, ATE 2.4 m over 3 s on tuning seed 1), apparently because a large "
    "plane leaves the point-to-plane term degenerate along the table; its photometric variant is the baseline. "
    "The simulated table's wood grain runs along the planks, so translation along the planks is observable "
    "mostly from the parts and the floor: masking every part (`--mask parts`) made the dense odometry drift by "
    "2–4 cm on tuning seeds, so by default only the hand is masked and Huber weights handle moved parts."
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--quick", action="store_true", help="two sessions of 90 frames, no castle")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--methods", default=",".join(METHODS),
                    help=f"comma-separated methods of {', '.join((*METHODS, IN_TRACKER, PARTS, FUSED))} "
                    f"(default: {','.join(METHODS)})")
    ap.add_argument("--sessions", default=None, help="only these sessions, e.g. guess-1/handheld/100,static/sway/102 "
                    "(no castle)")
    ap.add_argument("--stem", default="odometry", help="results file name: results/STEM.md/.json (default odometry)")
    args = ap.parse_args(argv)
    methods = tuple(m for m in args.methods.split(",") if m)
    bad = [m for m in methods if m not in (*METHODS, IN_TRACKER, PARTS, FUSED)]
    if bad or "default" not in methods:
        known = ", ".join((*METHODS, IN_TRACKER, PARTS, FUSED))
        print(f"error: --methods {args.methods!r}: give methods of {known}, including default", file=sys.stderr)
        return 2
    info = machine_info()
    info["load_1min_at_start"] = info.pop("load_avg_1min")
    RESULTS.mkdir(parents=True, exist_ok=True)
    sessions, plots = [], []
    todo = SESSIONS[:2] if args.quick else SESSIONS
    if args.sessions:
        todo = []
        for item in args.sessions.split(","):
            scenario, motion, seed = item.split("/")
            if int(seed) < 100:
                print(f"error: --sessions {item}: held-out seeds are >= 100", file=sys.stderr)
                return 2
            todo.append((scenario, motion, int(seed)))
    n = 90 if args.quick else args.frames
    prefix = "" if args.stem == "odometry" else args.stem.removeprefix("odometry_") + "_"
    for scenario, motion, seed in todo:
        s, trajs = simulated_session(scenario, motion, seed, n, methods)
        sessions.append(s)
        if not args.no_write:
            title = f"{scenario}, {motion} camera, seed {seed}"
            plots.append(plot(f"{prefix}{scenario}_{motion}_{seed}", trajs, title))
    if not args.quick and not args.sessions:
        castle = castle_session()
        if castle is not None:
            sessions.append(castle[0])
            if not args.no_write:
                plots.append(plot("castle-simu", castle[1], "castle-simu (ViSP, external)"))
    res = {"machine": info, "sessions": sessions, "plots": plots, "notes": NOTES,
           "load_1min_at_end": round(os.getloadavg()[0], 2)}
    md = markdown(res)
    print(md)
    if not args.no_write:
        (RESULTS / f"{args.stem}.json").write_text(json.dumps(res, indent=2) + "\n")
        (RESULTS / f"{args.stem}.md").write_text(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
