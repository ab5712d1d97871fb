"""Dynamic model of each part (spec sections 4.6, 4.7, 4.11) and the pose estimate (4.13).

State per part and particle: a pose change δr = (δp, δθ) relative to a reference pose that is renewed every
frame (the particle's pose of the previous frame, as in the reference code), and the velocity
(v, ω) in the camera frame. Per frame (eq. 4.26, with the same noise sample in both rows):

    v_t  = k_v v_t−1 + b u_t + w_t,      w_t ~ N(0, diag(σ_v² I3, σ_ω² I3))
    δr_t = v_t,   p_t = p_ref + δp_t,   R_t = exp([δθ_t]×) R_ref      (delta applied in the camera frame)

u_t = (u_x, u_y, u_z, 0, 0, 0) is the colour control input (4.38–4.40) scaled by the detection's reliability
score, zero when the part is not detected. The estimate is the weighted mean position and the proper
rotation mean (principal eigenvector of Σ w q qᵀ over sign-aligned quaternions).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.geometry.fma import fma, matmul33
from tracker.geometry.pose import Pose, matrix_to_quat, quat_to_matrix


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (M, 3, 3) of rotation vectors (M, 3) (Rodrigues, exact for small angles)."""
    w = np.asarray(w, np.float64).reshape(-1, 3)
    th = np.linalg.norm(w, axis=1)
    small = th < 1e-9
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    K = np.zeros((w.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -w[:, 2], w[:, 1]
    K[:, 1, 0], K[:, 1, 2] = w[:, 2], -w[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -w[:, 1], w[:, 0]
    return np.eye(3)[None] + a[:, None, None] * K + b[:, None, None] * (K @ K)


def propagate(
    p_ref: np.ndarray, R_ref: np.ndarray, v_prev: np.ndarray, u: np.ndarray, noise: np.ndarray, k_v: float, b: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of (4.26) for M particles of one part.

    ``p_ref`` (M, 3), ``R_ref`` (M, 3, 3): reference (previous) poses; ``v_prev`` (M, 6) = (v, ω);
    ``u`` (3,) control input (metres); ``noise`` (M, 6) samples of w. Returns (p, R, v), new arrays.

    One numba pass (:func:`propagate_part_into` on the arrays seen as one part's column) forms the operations of
    :func:`propagate_numpy` in its order, the two 3×3 products as numpy's matmul rounds them
    (:func:`tracker.geometry.fma.matmul33`), so that the result is :func:`propagate_numpy`'s bit for bit without
    numpy's per-matrix product calls.
    """
    m = p_ref.shape[0]
    p = np.empty((m, 1, 3))
    R = np.empty((m, 1, 3, 3))
    v = np.empty((m, 1, 6))
    propagate_part_into(np.asarray(p_ref, np.float64)[:, None], np.asarray(R_ref, np.float64)[:, None],
                        np.asarray(v_prev, np.float64)[:, None], np.arange(m, dtype=np.int64), 0,
                        np.asarray(noise, np.float64), np.asarray(u, np.float64).reshape(3), float(k_v), float(b), p,
                        R, v)
    return p[:, 0], R[:, 0], v[:, 0]


@nb.njit(cache=True)
def rodrigues_terms(w0: float, w1: float, w2: float, K: np.ndarray) -> tuple[float, float]:
    """Rodrigues' formula ``R = I + a K + b K²`` of the rotation vector ``(w0, w1, w2)`` (radians): writes its skew
    matrix into ``K`` (3×3) and returns ``(a, b) = (sin θ / θ, (1 − cos θ) / θ²)``, by their series below 1e-9 rad."""
    th = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if th < 1e-9:
        fa = 1.0 - th**2 / 6.0
        fb = 0.5 - th**2 / 24.0
    else:
        fa = np.sin(th) / th
        fb = (1.0 - np.cos(th)) / th**2
    K[0, 0], K[0, 1], K[0, 2] = 0.0, -w2, w1
    K[1, 0], K[1, 1], K[1, 2] = w2, 0.0, -w0
    K[2, 0], K[2, 1], K[2, 2] = -w1, w0, 0.0
    return fa, fb


@nb.njit(cache=True)
def propagate_part_into(p_all, R_all, v_all, rows, obj, noise, u, k_v, b, p_out, R_out, v_out):
    """:func:`propagate` of part ``obj`` for the particles ``rows`` (N,) of ``p_all`` (M, K, 3), ``R_all``
    (M, K, 3, 3), ``v_all`` (M, K, 6) (e.g. last frame's particles in the current order: rows = the resamplings
    composed), written straight into column ``obj`` of ``p_out`` (N, K, 3), ``R_out``, ``v_out``: the values of
    ``p_out[:, obj], R_out[:, obj], v_out[:, obj] = propagate(p_all[rows, obj], R_all[rows, obj], v_all[rows, obj],
    u, noise, k_v, b)`` without the gathered and returned arrays.

    Per particle: ``v = k_v v_prev + noise`` (+ ``b u`` on the linear part), ``p = p_ref + v[:3]``, the skew matrix
    ``K`` of ω = ``v[3:]`` and Rodrigues' coefficients ``fa`` = sin θ / θ, ``fb`` = (1 − cos θ) / θ² (series below
    1e-9 rad), ``E = (I + fa K) + fb (K K)`` and ``R = E R_ref``, with the operations of :func:`propagate_numpy` and
    :func:`rotvec_to_matrix` (same values; the products rounded as numpy's matmul,
    :func:`tracker.geometry.fma.matmul33`). The particles' entries are read and written by index (no per-particle
    array views: a view per argument and particle cost about as much as the arithmetic)."""
    K = np.empty((3, 3))
    KK = np.empty((3, 3))
    E = np.empty((3, 3))
    for j in range(rows.shape[0]):
        r = rows[j]
        for a in range(6):
            v_out[j, obj, a] = k_v * v_all[r, obj, a] + noise[j, a]
        for a in range(3):
            v_out[j, obj, a] += b * u[a]
            p_out[j, obj, a] = p_all[r, obj, a] + v_out[j, obj, a]
        fa, fb = rodrigues_terms(v_out[j, obj, 3], v_out[j, obj, 4], v_out[j, obj, 5], K)
        matmul33(K, K, KK)
        for a in range(3):
            for c in range(3):
                eye = 1.0 if a == c else 0.0
                E[a, c] = (eye + fa * K[a, c]) + fb * KK[a, c]
        for a in range(3):  # R = E @ R_ref as matmul33 forms it
            for c in range(3):
                R_out[j, obj, a, c] = fma(E[a, 2], R_all[r, obj, 2, c],
                                          fma(E[a, 1], R_all[r, obj, 1, c], E[a, 0] * R_all[r, obj, 0, c]))


def propagate_numpy(
    p_ref: np.ndarray, R_ref: np.ndarray, v_prev: np.ndarray, u: np.ndarray, noise: np.ndarray, k_v: float, b: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`propagate` in numpy alone (the reference its kernel is tested against)."""
    v = k_v * v_prev + noise
    v[:, :3] += b * np.asarray(u, np.float64)[None, :]
    p = p_ref + v[:, :3]
    R = rotvec_to_matrix(v[:, 3:]) @ R_ref
    return p, R, v


def sample_noise(
    rng: np.random.Generator,
    m: int,
    sigma_v: float,
    sigma_w: float,
    wide_fraction: float = 0.0,
    wide_scale: float = 1.0,
) -> np.ndarray:
    """Noise samples (m, 6): N(0, σ_v²) on the 3 linear and N(0, σ_ω²) on the 3 angular components.

    With ``wide_fraction`` > 0 a random share of the samples uses ``wide_scale`` times the standard deviations
    (a two-component Gaussian mixture: precise at rest, still able to follow fast motion).
    """
    w = rng.standard_normal((m, 6))
    if wide_fraction > 0.0 and wide_scale != 1.0:
        _scale_noise(w, rng.random(m), float(wide_fraction), float(wide_scale), float(sigma_v), float(sigma_w))
    else:
        _scale_noise(w, np.empty(0), 0.0, 1.0, float(sigma_v), float(sigma_w))
    return w


@nb.njit(cache=True)
def _scale_noise(w, draws, wide_fraction, wide_scale, sigma_v, sigma_w):
    """In place: row j of the standard normal samples ``w`` (m, 6) times σ_v·s_j (linear) and σ_ω·s_j (angular),
    s_j = ``wide_scale`` where ``draws[j] < wide_fraction`` else 1 (``draws`` empty: s_j = 1); the products of
    :func:`sample_noise`'s numpy form (σ·s first, then the sample), same values."""
    for j in range(w.shape[0]):
        s = 1.0
        if draws.shape[0] > 0 and draws[j] < wide_fraction:
            s = wide_scale
        fv = sigma_v * s
        fw = sigma_w * s
        for a in range(3):
            w[j, a] *= fv
            w[j, a + 3] *= fw


def color_input(
    center: tuple[float, float] | None,
    score: float,
    estimate: Pose,
    depth: np.ndarray | None,
    intrinsics: Intrinsics,
    lambda_z: float,
    radius_px: float,
    surface_offset: float,
    max_z_jump: float = 0.1,
    mask: np.ndarray | None = None,
    bias_px: np.ndarray | None = None,
) -> np.ndarray:
    """Colour control input (u_x, u_y, u_z) of eqs 4.38–4.40, metres.

    * ``center``: colour-tracker pixel (u, v) or ``None`` (→ zero input); ``score`` its reliability s in 0..1.
    * ``estimate``: the part's estimated pose of the previous frame (r = its position).
    * u_z: z is the mean valid depth within ``radius_px`` of the pixel (full resolution). The measured depth is
      of the visible surface, so ``surface_offset`` (distance from that surface to the part centre along z,
      from rendering the estimate) is added before comparing with r_z. When no depth is valid there or the
      correction is larger than ``max_z_jump`` metres (a hand in front, a wrong blob), u_z = 0.
    * ``mask`` (H, W bool, optional): the part's colour blob. Then only pixels inside it count and their median is
      used instead of the mean (not in the spec: next to a hand the window around the centroid of a partly hidden
      blob also holds hand pixels, whose depth would pull the part toward the camera).
    """
    if center is None or score <= 0.0:
        return np.zeros(3)
    px, py = float(center[0]), float(center[1])
    if not (np.isfinite(px) and np.isfinite(py)):
        return np.zeros(3)
    r = estimate.t
    if bias_px is not None:
        px, py = px - float(bias_px[0]), py - float(bias_px[1])
    ux = ((px - intrinsics.cx) * r[2] / intrinsics.fx - r[0]) * score
    uy = ((py - intrinsics.cy) * r[2] / intrinsics.fy - r[1]) * score
    uz = 0.0
    if bias_px is not None:
        px, py = float(center[0]), float(center[1])
    if depth is not None and lambda_z > 0.0:
        h, w = depth.shape
        rad = max(0, int(np.ceil(radius_px)))
        u0, u1 = max(0, int(round(px)) - rad), min(w, int(round(px)) + rad + 1)
        v0, v1 = max(0, int(round(py)) - rad), min(h, int(round(py)) + rad + 1)
        if u0 < u1 and v0 < v1:
            if mask is not None and depth.dtype == np.float32 and mask.dtype == np.bool_:
                # the blob's valid depths in the disc, gathered and their median taken in one compiled pass
                n_vals, z_obs = _disc_median(depth, mask, u0, u1, v0, v1, px, py, max(radius_px, 0.5) ** 2)
            else:
                patch = depth[v0:v1, u0:u1]
                vv, uu = np.mgrid[v0:v1, u0:u1]
                inside = (uu - px) ** 2 + (vv - py) ** 2 <= max(radius_px, 0.5) ** 2
                if mask is not None:
                    inside &= mask[v0:v1, u0:u1]
                vals = patch[inside & np.isfinite(patch) & (patch > 0)]
                n_vals = vals.size
                if n_vals:
                    z_obs = float(np.median(vals)) if mask is not None else float(vals.mean())
            if n_vals:
                dz = z_obs + surface_offset - r[2]
                if abs(dz) <= max_z_jump:
                    uz = dz * lambda_z * score
    return np.array([ux, uy, uz])


@nb.njit(cache=True)
def _disc_median(depth, mask, u0, u1, v0, v1, px, py, r2):
    """Count and median (float) of the valid depths (finite, > 0) of float32 ``depth`` at the pixels of the window
    ``[v0, v1) × [u0, u1)`` that lie in ``mask`` and within the disc ``(u − px)² + (v − py)² <= r2`` around the
    pixel ``(px, py)``: the values and median of :func:`color_input`'s numpy form (median 0.0 with no value)."""
    vals = np.empty((v1 - v0) * (u1 - u0), np.float32)
    n = 0
    for v in range(v0, v1):
        dv = (v - py) ** 2
        for u in range(u0, u1):
            if not ((u - px) ** 2 + dv <= r2 and mask[v, u]):
                continue
            d = depth[v, u]
            if np.isfinite(d) and d > 0:
                vals[n] = d
                n += 1
    if n == 0:
        return 0, 0.0
    return n, float(np.median(vals[:n]))


def mean_rotation(R: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted rotation mean (3, 3): principal eigenvector of Σ w q qᵀ (quaternion sign ambiguity removed)."""
    q = matrix_to_quat(np.asarray(R, np.float64).reshape(-1, 3, 3))
    w = np.asarray(weights, np.float64).reshape(-1)
    M = (q * w[:, None]).T @ q
    vals, vecs = np.linalg.eigh(M)
    return quat_to_matrix(vecs[:, -1])


def mean_pose(p: np.ndarray, R: np.ndarray, weights: np.ndarray) -> Pose:
    """Weighted mean position and rotation mean of particle poses ``p`` (N, 3), ``R`` (N, 3, 3)."""
    w = np.asarray(weights, np.float64)
    w = w / w.sum()
    return Pose.from_rt(mean_rotation(R, w), (w[:, None] * p).sum(axis=0))


def mean_poses(p: np.ndarray, R: np.ndarray, weights: np.ndarray) -> list[Pose]:
    """:func:`mean_pose` of every part at once: particle positions ``p`` (N, K, 3), rotations ``R`` (N, K, 3, 3),
    weights (N,) → K poses. The quaternions of all parts in one pass and the K eigen-decompositions in one call;
    each part's sums as :func:`mean_pose` forms them (the same poses)."""
    w = np.asarray(weights, np.float64)
    w = w / w.sum()
    k = p.shape[1]
    q_all = matrix_to_quat(np.asarray(R, np.float64))  # (N, K, 4)
    M = np.empty((k, 4, 4))
    for i in range(k):
        q = np.ascontiguousarray(q_all[:, i])
        M[i] = (q * w[:, None]).T @ q
    _, vecs = np.linalg.eigh(M)
    t = weighted_positions(w, np.asarray(p, np.float64))
    return [Pose.from_rt(quat_to_matrix(vecs[i, :, -1]), t[i].copy()) for i in range(k)]


@nb.njit(cache=True)
def weighted_positions(w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Per part, ``Σ_n w[n] p[n, i]`` (K, 3) of the particle positions ``p`` (N, K, 3): the sums of
    ``(w[:, None] * p[:, i]).sum(axis=0)`` in its order (over the particles in turn; the same values)."""
    n, k = p.shape[0], p.shape[1]
    out = np.zeros((k, 3))
    if n == 0:
        return out
    for i in range(k):
        for a in range(3):
            acc = w[0] * p[0, i, a]
            for j in range(1, n):
                acc += w[j] * p[j, i, a]
            out[i, a] = acc
    return out


@nb.njit(cache=True)
def rotate_left(Rd: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``Rd @ R[n]`` for every rotation of ``R`` (N, 3, 3): a new (N, 3, 3) array, each entry summed in the order
    ``np.einsum("ij,njk->nik", Rd, R)`` sums it (the same values), without its per-call overhead."""
    n = R.shape[0]
    out = np.empty((n, 3, 3))
    for j in range(n):
        for a in range(3):
            for b in range(3):
                out[j, a, b] = Rd[a, 0] * R[j, 0, b] + Rd[a, 1] * R[j, 1, b] + Rd[a, 2] * R[j, 2, b]
    return out
