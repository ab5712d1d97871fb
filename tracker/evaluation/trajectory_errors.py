"""Camera-trajectory errors: absolute trajectory error (ATE) and relative pose error (RPE) after Sturm et al.,
"A Benchmark for the Evaluation of RGB-D SLAM Systems" (IROS 2012).

Both trajectories are lists of camera → world poses at the same timestamps with the same world frame (here the
first camera frame, so no alignment is applied: the figures include any error of the first frames). Translations
in metres, rotations in degrees; RPE over a time step ``delta`` seconds is reported per second of travel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.geometry.pose import Pose


@dataclass(frozen=True)
class TrajectoryErrors:
    """ATE RMSE / max (metres), rotation RMSE / max (degrees), RPE translation RMSE (metres per second) and RPE
    rotation RMSE (degrees per second) over ``delta`` seconds, and the number of poses compared."""

    ate_rmse: float
    ate_max: float
    rot_rmse_deg: float
    rot_max_deg: float
    rpe_trans_per_s: float
    rpe_rot_deg_per_s: float
    delta: float
    n: int

    def to_dict(self) -> dict:
        return {
            "ate_rmse_mm": round(1e3 * self.ate_rmse, 3), "ate_max_mm": round(1e3 * self.ate_max, 3),
            "rot_rmse_deg": round(self.rot_rmse_deg, 4), "rot_max_deg": round(self.rot_max_deg, 4),
            "rpe_mm_per_s": round(1e3 * self.rpe_trans_per_s, 3), "rpe_deg_per_s": round(self.rpe_rot_deg_per_s, 4),
            "delta_s": self.delta, "n": self.n,
        }


def trajectory_errors(times: np.ndarray, estimate: list[Pose], truth: list[Pose],
                      delta: float = 1.0) -> TrajectoryErrors:
    """Errors of ``estimate`` against ``truth`` (same length, same timestamps ``times`` in seconds)."""
    if len(estimate) != len(truth) or len(estimate) != len(times):
        raise ValueError(f"trajectory_errors: {len(estimate)} estimated, {len(truth)} true poses and {len(times)} "
                         "timestamps must match")
    if not estimate:
        raise ValueError("trajectory_errors: empty trajectory")
    times = np.asarray(times, dtype=np.float64)
    te = np.array([e.translation_error(t) for e, t in zip(estimate, truth, strict=True)])
    re = np.degrees([e.rotation_error(t) for e, t in zip(estimate, truth, strict=True)])
    rpe_t, rpe_r = [], []
    j = 0
    for i in range(len(times)):
        while j < len(times) and times[j] - times[i] < delta - 1e-9:
            j += 1
        if j >= len(times):
            break
        dt = times[j] - times[i]
        d_est = estimate[i].inverse() @ estimate[j]
        d_true = truth[i].inverse() @ truth[j]
        err = d_true.inverse() @ d_est
        rpe_t.append(float(np.linalg.norm(err.t)) / dt)
        rpe_r.append(float(np.degrees(Pose().rotation_error(err))) / dt)

    def rms(x) -> float:
        return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")

    return TrajectoryErrors(rms(te), float(te.max()), rms(re), float(re.max()), rms(rpe_t), rms(rpe_r), float(delta),
                            len(times))
