r"""Localisation inside the current ASR (method.md §6): odometry, Röfer histogram matching, Kalman filter.

State :math:`\mathbf{x} = (x, y, \theta)` is the robot pose in the **ASR frame** (m, m, rad), with
covariance :math:`P`, in a filterpy :class:`~filterpy.kalman.KalmanFilter` (``dim_x = dim_z = 3``).

**Prediction.** The odometry increment :math:`\delta = o_{k-1}^{-1} \oplus o_k` (robot frame) moves
the pose to :math:`\hat{\mathbf{x}} = \mathbf{x} \oplus \delta`; filterpy's ``predict`` (its arithmetic,
without its per-call overhead: :func:`_kalman_predict`) is given
:math:`F = I`, :math:`B = I` and :math:`u = \hat{\mathbf{x}} - \mathbf{x}` (angle wrapped), so
:math:`P \leftarrow P + Q` with :math:`Q = \mathrm{diag}(\sigma_t^2, \sigma_t^2, \sigma_r^2)`,
:math:`\sigma_t = \sigma_{t0} + k_t |\delta_{xy}|`, :math:`\sigma_r = \sigma_{r0} + k_r |\delta_\theta|
+ k_t |\delta_{xy}|` (the pose is so close to linear over one scan that an EKF Jacobian changes nothing).

**Measurement (Röfer 2002, "Using histogram correlation to create consistent laser scan maps").**
The reference is the ASR's first viewpoint scan plus its ``reference_scans`` latest ones, as points
in the ASR frame.

1. *Rotation.* Directions :math:`\phi` of the vectors between scan points a few beams apart
   (at most ``direction_max_gap`` apart) are histogrammed modulo 180° in 1° bins, lightly smoothed:
   :math:`H_c` for the scan (directions taken in the ASR frame at the predicted :math:`\hat\theta`),
   :math:`H_r` for the reference. The circular cross-correlation
   :math:`C(s) = \sum_b H_c(b) H_r(b + s)` over :math:`|s| \le` ``max_rotation`` peaks at
   :math:`s^*` (refined by a parabola through the peak): :math:`\theta_m = \hat\theta + s^* \Delta`.
2. *Translation.* The reference's main direction :math:`\alpha` is the peak of :math:`H_r`. Scan
   points placed at :math:`(\hat x, \hat y, \theta_m)` and the reference points are rotated by
   :math:`-\alpha` to coordinates :math:`(u, v)`; histograms of u and of v (``xy_bin``) are
   cross-correlated over :math:`|s| \le` ``max_translation``: peaks :math:`s_u, s_v` give the
   correction :math:`R(\alpha)(s_u, s_v)^T` and :math:`(x_m, y_m)`.
3. *Quality.* Each correlation's quality is its normalised peak
   :math:`q = C(s^*) / \sqrt{\sum H_c^2 \sum H_r^2}` (cosine similarity, 0..1).
   :math:`R = \mathrm{diag}(\sigma_{xy}^2/q_u^2, \sigma_{xy}^2/q_v^2)` in the (u, v) axes, rotated
   to (x, y) by :math:`\alpha`, and :math:`\sigma_\theta^2/q_\theta^2` for the angle: an axis
   without structure (along a corridor) gets a low q and hardly moves the estimate. An axis with
   :math:`q <` ``min_quality`` is not measured (variance 1e6); a rotation with
   :math:`q_\theta <` ``min_quality`` rejects the whole match.

**Update and gate.** Innovation :math:`\mathbf{y} = \mathbf{z} - \hat{\mathbf{x}}` (angle wrapped),
:math:`S = P + R`; the match is rejected when :math:`\mathbf{y}^T S^{-1} \mathbf{y} >` ``gate_chi2``,
else filterpy's ``update(z, R)`` (:math:`H = I`; its arithmetic, without its overhead:
:func:`_kalman_update`) fuses it.

**Viewpoint refinement (beyond Röfer; ``refine``).** A viewpoint scan becomes part of the reference,
so its pose error is inherited by every later match in the ASR, and by the frame of the next ASR
created from it: on the Intel log the histogram matches drifted +2° per ASR, which put revisits 11 m
from the places they revisit. Before a scan is taken as a viewpoint, :meth:`Localiser.refine` aligns
its points to the reference points (densified along their surfaces to one every ``refine_spacing``)
by point-to-point ICP (closest point within a gate shrinking from ``refine_start`` to
``refine_inlier``; the closed-form rigid motion of the pairs each step, ``refine_iterations`` steps
at most), from the filtered pose. It is a measurement like a match: rejected when fewer than
``refine_min_inliers`` of the points end within the last gate, else fused with the covariance of
point-to-plane alignment, :math:`R = \sigma^2 (\sum_i J_i^T J_i)^{-1}` over the pairs whose
reference point has a surface direction (normal :math:`n_i`, lever :math:`r_i` from the robot:
:math:`J_i = (n_i^T, r_i \times n_i)`), with :math:`\sigma` the pairs' RMS point-to-plane residual
(at least ``refine_sigma_floor``) times :math:`\sqrt{N / \text{refine_effective_points}}`
(neighbouring points' errors are not independent): along a corridor, where nothing constrains the
motion, it hardly moves the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter

from mapper.icp import PointGrid, icp
from mapper.jit import kernel
from mapper.params import MapperParams
from mapper.se2 import Pose, compose, transform_points, wrap

_STRIDE = 4  # beams between the two points of a direction sample: ~0.1-0.3 m baseline indoors
_SMOOTH = np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 9.0
_NOT_MEASURED = 1e6
#: m: consecutive reference points closer than this lie on one surface (refine); beams 1° apart
#: are 5 cm apart at 3 m, 13 cm at 7.5 m.
_DENSE_GAP = 0.15
#: m: cell of the grid refine() finds nearest reference points in (a reference's densified points
#: lie 2 cm apart along its surfaces): on 280 Intel refinements an ICP takes 0.21 ms with 0.1-0.15
#: m cells, 0.23 with 0.05 or 0.2, 0.27 with 0.3
_ICP_CELL = 0.15
# What _build_reference makes (never changed in place): kept and restored as a whole.
_REFERENCE = (
    "_refs", "_ref_ready", "_hr", "_hr_shifted", "_hr_norm", "_alpha", "_ra", "_uv0", "_huv", "_offsets",
    "_nuv", "_huv_norm", "_ref_points", "_ref_angles", "_ref_grid",
)


@dataclass(frozen=True, slots=True)
class Match:
    """One histogram match: measured pose (ASR frame), qualities (0..1), and whether it was fused."""

    pose: Pose
    q_theta: float
    q_u: float
    q_v: float
    accepted: bool
    reason: str


@kernel
def _chords(xy: np.ndarray, max_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Directions and surface angles of a sweep (rad, in the frame of ``xy``), both from the chords
    between points ``_STRIDE`` apart.

    *Directions* (in [0, pi), undirected) of the chords 5 cm to ``max_gap`` long: the rotation
    histogram's samples. *Surface angles*, one per point: the direction of the chord between its
    neighbours two beams either side, when they are close together, or farther apart (a wall seen
    at a grazing angle) but in line with the point; NaN otherwise (an isolated point: a leg, a
    corner). Compiled (:mod:`mapper.jit`): one pass instead of about 20 numpy calls."""
    k = xy.shape[0]
    ang = np.full(k, np.nan)
    if k <= _STRIDE:
        return np.zeros(0), ang
    h = _STRIDE // 2
    dirs = np.empty(k - _STRIDE)
    nd = 0
    for i in range(k - _STRIDE):
        dx = xy[i + _STRIDE, 0] - xy[i, 0]
        dy = xy[i + _STRIDE, 1] - xy[i, 1]
        n = math.hypot(dx, dy)
        a = math.atan2(dy, dx)
        short = n < max_gap
        if n > 0.02:
            if short:
                ang[i + h] = a
            elif n < 8.0 * max_gap:
                rx = xy[i + h, 0] - xy[i, 0]
                ry = xy[i + h, 1] - xy[i, 1]
                if abs(dx * ry - dy * rx) / max(n, 1e-9) < 0.05:  # the point's offset from the chord
                    ang[i + h] = a
        if n > 0.05 and short:
            dirs[nd] = a % math.pi
            nd += 1
    return dirs[:nd], ang


@kernel
def _axis_weight(angle: float, alpha: float) -> tuple[float, float]:
    """How much a point tells about position along u (the direction ``alpha``) and along v: the
    components of its surface's normal on the two axes (its surface angle ``angle``; rad, one
    frame). A wall along u says nothing about u (its points only crowd where the laser was, which
    drags a match back to the reference's viewpoint); a wall across u says all. An isolated point
    (surface angle NaN: a leg) tells about both."""
    rel = angle - alpha
    if math.isnan(rel):
        return 1.0, 1.0
    return abs(math.sin(rel)), abs(math.cos(rel))


def _hist_circular(angles: np.ndarray, nbins: int) -> np.ndarray:
    b = np.floor(angles * (nbins / np.pi)).astype(int) % nbins
    h = np.bincount(b, minlength=nbins).astype(float)
    # circular smoothing: direction noise spreads a wall over a few bins
    hp = np.concatenate([h[-2:], h, h[:2]])
    return np.convolve(hp, _SMOOTH, mode="valid")


@kernel
def _peak(c: np.ndarray) -> tuple[float, int, float]:
    """The maximum of c: its index refined by a parabola through it and its neighbours, its index,
    and its value."""
    i = int(np.argmax(c))
    top = c[i]
    if 0 < i < len(c) - 1:
        lo, hi = c[i - 1], c[i + 1]
        den = lo - 2.0 * top + hi
        if den < 0:
            return i + 0.5 * (lo - hi) / den, i, top
    return float(i), i, top


def _rot(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


class Localiser:
    """Pose of the robot in the current ASR frame; see the module docstring for the maths."""

    def __init__(self, params: MapperParams):
        self.p = params
        self.kf = KalmanFilter(dim_x=3, dim_z=3)
        # constant model matrices: F = B = H = I (see the module docstring)
        self.kf.F, self.kf.B, self.kf.H = np.eye(3), np.eye(3), np.eye(3)
        self._nb = round(math.pi / params.angle_bin)
        w = math.ceil(params.max_rotation / params.angle_bin)
        self._rot_shifts = np.arange(-w, w + 1)
        self._rot_index = (np.arange(self._nb)[None, :] + self._rot_shifts[:, None]) % self._nb
        self._tw = math.ceil(params.max_translation / params.xy_bin)
        self._gates = np.geomspace(  # m: ICP's shrinking correspondence gates
            params.refine_start, params.refine_inlier, params.refine_iterations)
        self.reset()

    def reset(self, pose: Pose = (0.0, 0.0, 0.0)) -> None:
        """Start over in a new ASR frame at ``pose`` (its creating scan: the frame's origin)."""
        self.kf.x = np.array(pose, dtype=float)
        self.kf.P = np.diag([1e-6, 1e-6, 1e-8])
        # (points, directions, surface angles, densified points, their surface angles), ASR frame
        self._refs: list[tuple[np.ndarray, ...]] = []
        self._ref_ready = False

    @property
    def pose(self) -> Pose:
        x, y, th = self.kf.x.tolist()
        return (x, y, wrap(th))

    def predict(self, delta: Pose) -> Pose:
        """Move by the odometry increment ``delta`` (robot frame: m, m, rad); returns the prediction."""
        p = self.p
        cur = self.pose
        new = compose(cur, delta)
        u = np.array([new[0] - cur[0], new[1] - cur[1], wrap(new[2] - cur[2])])
        trans = math.hypot(delta[0], delta[1])
        st = p.odom_sigma_floor_xy + p.odom_sigma_per_m * trans
        sr = p.odom_sigma_floor_theta + p.odom_sigma_per_rad * abs(delta[2]) + p.odom_sigma_per_m * trans
        kf = self.kf
        kf.x, kf.P = _kalman_predict(kf.x, kf.P, u, np.diag([st * st, st * st, sr * sr]))
        kf.x[2] = wrap(float(kf.x[2]))
        return self.pose

    def reference(self) -> dict:
        """The matching reference as built, to give back to :meth:`restore_reference` later."""
        ref = {k: getattr(self, k) for k in _REFERENCE if hasattr(self, k)}
        ref["_refs"] = list(self._refs)
        return ref

    def restore_reference(self, ref: dict) -> None:
        """Match against a reference kept by :meth:`reference` (after :meth:`reset`): the same as
        adding its scans again, without rebuilding the histograms."""
        for k, v in ref.items():
            setattr(self, k, v)
        self._refs = list(ref["_refs"])

    def add_reference(self, xy: np.ndarray, pose: Pose) -> None:
        """Add a viewpoint scan (points ``xy`` (K, 2), robot frame) seen from ``pose`` (ASR frame)."""
        self.add_references([(xy, pose)])

    def add_references(self, scans: list[tuple[np.ndarray, Pose]]) -> None:
        """:meth:`add_reference` for each (points, pose) in turn, the histograms built once."""
        gap = self.p.direction_max_gap
        for xy, pose in scans:
            pts = transform_points(pose, xy)
            if self._refs and len(self._refs) > self.p.reference_scans:
                del self._refs[1]  # keep the first (anchors the frame) and the latest ones
            dirs, ang = _chords(pts, gap)
            self._refs.append((pts, dirs, ang, *_densify(pts, ang, self.p.refine_spacing)))
        if scans:
            self._build_reference()

    def _build_reference(self) -> None:
        p = self.p
        dirs = np.concatenate([r[1] for r in self._refs])
        pts = np.concatenate([r[0] for r in self._refs])
        wts = np.concatenate([r[2] for r in self._refs])
        if len(dirs) < 10 or len(pts) < 10:
            self._ref_ready = False
            return
        # for refine(): the reference scans densified along their surfaces, and the tree on demand
        self._ref_points = np.concatenate([r[3] for r in self._refs])
        self._ref_angles = np.concatenate([r[4] for r in self._refs])
        self._ref_grid = None
        self._hr = _hist_circular(dirs, self._nb)
        self._hr_shifted = self._hr[self._rot_index]  # (shifts, bins): the rotation correlation is one matvec
        self._hr_norm = float(np.sqrt(self._hr @ self._hr))
        self._alpha = (_peak(self._hr)[0] + 0.5) * p.angle_bin
        self._ra = _rot(self._alpha)  # the (u, v) axes in the ASR frame, for correct()
        tw = self._tw
        huv, u0, v0, nu, nv, norm_u, norm_v = _uv_histograms(
            pts, wts, self._alpha, p.max_translation, p.xy_bin, tw)
        self._huv, self._uv0, self._nuv = huv, np.array([u0, v0]), np.array([nu, nv])
        self._offsets = np.array([tw, nu + 3 * tw])  # where bin 0 of u and of v sit in huv
        self._huv_norm = (norm_u, norm_v)
        self._ref_ready = True

    def refine(self, xy: np.ndarray) -> Match | None:
        """Align the scan points ``xy`` (K, 2, robot frame) to the reference points by ICP from the
        filtered pose, and fuse the result (see "Viewpoint refinement" in the module docstring);
        for a scan about to become a viewpoint. None without a reference; else the measurement
        (ASR frame; ``q_u``: fraction of points within ``refine_inlier`` of the reference after
        alignment, ``q_v``: their RMS point-to-plane residual in m, ``q_theta`` 1)."""
        p = self.p
        if not p.refine or not self._ref_ready or len(xy) < 20:
            return None
        ref = self._ref_points
        if self._ref_grid is None:
            self._ref_grid = PointGrid(ref, _ICP_CELL)
        grid = self._ref_grid
        kf = self.kf
        n, x, y, th, cur, j = icp(np.ascontiguousarray(xy, dtype=float), ref, float(kf.x[0]),
                                   float(kf.x[1]), float(kf.x[2]), self._gates, p.refine_inlier,
                                   grid.cell, grid.arrays)
        if n < 20:
            return Match(self.pose, 0.0, 0.0, 0.0, False, "refine: too few pairs")
        ok = j >= 0
        inliers = float(ok.mean())
        pose = (x, y, wrap(th))
        if inliers < p.refine_min_inliers:
            return Match(pose, 1.0, inliers, 0.0, False, "refine: inliers")
        # point-to-plane information of the pairs whose reference point lies on a surface
        j = j[ok]
        ang = self._ref_angles[j]
        on = np.isfinite(ang)
        if np.count_nonzero(on) < 10:
            return Match(pose, 1.0, inliers, 0.0, False, "refine: no surfaces")
        nx, ny = -np.sin(ang[on]), np.cos(ang[on])
        pts, q = cur[ok][on], ref[j[on]]
        res = (pts[:, 0] - q[:, 0]) * nx + (pts[:, 1] - q[:, 1]) * ny
        lever = (pts[:, 0] - x) * ny - (pts[:, 1] - y) * nx
        jac = np.stack([nx, ny, lever])  # (3, N): d residual / d(x, y, theta)
        info = jac @ jac.T
        n = len(res)
        rms = float(np.sqrt(np.mean(res * res)))
        sigma2 = max(rms, p.refine_sigma_floor) ** 2 * n / min(n, p.refine_effective_points)
        try:
            r = sigma2 * np.linalg.inv(info + 1e-9 * np.eye(3))
        except np.linalg.LinAlgError:
            return Match(pose, 1.0, inliers, rms, False, "refine: degenerate")
        d2 = self._fuse(np.array([x, y, float(kf.x[2]) + wrap(th - float(kf.x[2]))]), 0.5 * (r + r.T))
        if d2 is not None:
            return Match(pose, 1.0, inliers, rms, False, f"refine: gate (d2 {d2:.1f})")
        return Match(pose, 1.0, inliers, rms, True, "refined")

    def correct(self, xy: np.ndarray) -> Match | None:
        """Match the scan points ``xy`` (K, 2, robot frame) to the reference; fuse if good."""
        if not self._ref_ready or len(xy) < 10:
            return None
        p = self.p
        kf = self.kf
        x, y, th = kf.x.tolist()
        th = wrap(th)
        n_dirs, s, q_th, ang = _rotation_match(xy, p.direction_max_gap, th, self._hr_shifted, self._hr_norm)
        if n_dirs < 10:
            return None
        th_m = wrap(th + s * p.angle_bin)
        if q_th < p.min_quality:
            return Match((x, y, th_m), q_th, 0.0, 0.0, False, "rotation quality")
        # scan points at (x, y, th_m) in the reference's main axes (u, v), correlated with its histograms
        su, sv, q_u, q_v = _translation_match(
            xy, ang, x, y, th_m, self._alpha, self._uv0, self._nuv, self._offsets, self._huv, self._tw,
            1.0 / p.xy_bin, self._huv_norm[0], self._huv_norm[1], p.axis_info_full, p.prominence_bins,
            p.prominence_full)
        shifts = np.array([su * p.xy_bin, sv * p.xy_bin])
        qs = (q_u, q_v)
        ra = self._ra
        corr = ra @ shifts
        var_uv = [(p.match_sigma_xy / q) ** 2 if q >= p.min_quality else _NOT_MEASURED for q in qs]
        r = np.zeros((3, 3))
        r[:2, :2] = (ra * var_uv) @ ra.T
        r[2, 2] = (p.match_sigma_theta / q_th) ** 2
        cx, cy = corr.tolist()
        zx, zy, zth = x + cx, y + cy, th + wrap(th_m - th)
        z = np.array([zx, zy, zth])
        pose_m = (zx, zy, wrap(zth))
        d2 = self._fuse(z, r)
        if d2 is not None:
            return Match(pose_m, q_th, qs[0], qs[1], False, f"gate (d2 {d2:.1f})")
        return Match(pose_m, q_th, qs[0], qs[1], True, "ok")

    def _fuse(self, z: np.ndarray, r: np.ndarray) -> float | None:
        """Fuse the measured pose ``z`` (ASR frame, its angle unwrapped near the state's) with
        covariance ``r`` unless the innovation fails the χ² gate; None when fused, else the squared
        Mahalanobis distance that failed."""
        kf = self.kf
        innov = z - kf.x
        innov[2] = wrap(float(innov[2]))
        d2 = _mahalanobis2(innov, kf.P + r)
        if d2 > self.p.gate_chi2:
            return d2
        kf.x, kf.P = _kalman_update(kf.x, kf.P, z, r)
        kf.x[2] = wrap(float(kf.x[2]))
        return None


@kernel
def _uv_histograms(
    pts: np.ndarray, wts: np.ndarray, alpha: float, pad: float, xy_bin: float, tw: int
) -> tuple[np.ndarray, float, float, int, int, float, float]:
    """The reference's translation histograms (:meth:`Localiser.correct`): its points ``pts``
    (K, 2, ASR frame) rotated by ``-alpha`` (rad) to (u, v), binned every ``xy_bin`` m from
    ``pad`` m below their least u and v, each weighted on each axis by :func:`_axis_weight` of its
    surface angle ``wts`` (rad). Returns u's and v's histograms side by side, each padded by the
    search window ``tw`` (bins), then a zero window where scan points beyond the reference fall
    (``huv``: tw zeros, u's ``nu`` bins, 2 tw zeros, v's ``nv`` bins, 2 tw + 1 zeros); the u and v
    of bin 0 (m); nu, nv; the two histograms' norms. Compiled (:mod:`mapper.jit`)."""
    c, s = math.cos(alpha), math.sin(alpha)
    n = pts.shape[0]
    u, v = np.empty(n), np.empty(n)
    u_lo = v_lo = np.inf
    u_hi = v_hi = -np.inf
    for i in range(n):
        u[i] = pts[i, 0] * c + pts[i, 1] * s
        v[i] = pts[i, 0] * -s + pts[i, 1] * c
        u_lo, u_hi = min(u_lo, u[i]), max(u_hi, u[i])
        v_lo, v_hi = min(v_lo, v[i]), max(v_hi, v[i])
    u0, v0 = u_lo - pad, v_lo - pad
    nu = math.floor((u_hi + pad - u0) / xy_bin) + 1
    nv = math.floor((v_hi + pad - v0) / xy_bin) + 1
    off_v = nu + 3 * tw
    huv = np.zeros(off_v + nv + 2 * tw + 1)
    for i in range(n):
        wu, wv = _axis_weight(wts[i], alpha)
        huv[tw + math.floor((u[i] - u0) / xy_bin)] += wu
        huv[off_v + math.floor((v[i] - v0) / xy_bin)] += wv
    norm_u = norm_v = 0.0
    for b in range(tw, tw + nu):
        norm_u += huv[b] * huv[b]
    for b in range(off_v, off_v + nv):
        norm_v += huv[b] * huv[b]
    return huv, u0, v0, nu, nv, math.sqrt(norm_u), math.sqrt(norm_v)


@kernel
def _rotation_correlation(dirs: np.ndarray, th: float, hr_shifted: np.ndarray) -> tuple[np.ndarray, float]:
    """The rotation correlation of :meth:`Localiser.correct`: the scan's chord directions ``dirs``
    (rad, robot frame) turned by ``th`` (rad) into a histogram H_c of ``nb`` bins over [0, pi),
    then C(s) = sum_b H_c(b) H_r(b + s) for each row s of ``hr_shifted`` (shifts, nb), the
    reference's histogram shifted; and the norm of H_c. Compiled (:mod:`mapper.jit`)."""
    nb = hr_shifted.shape[1]
    hc = np.zeros(nb)
    scale = nb / math.pi
    for d in dirs:
        hc[math.floor(((d + th) % math.pi) * scale) % nb] += 1.0
    c = np.zeros(hr_shifted.shape[0])
    norm = 0.0
    for b in range(nb):
        v = hc[b]
        if v != 0.0:
            norm += v * v
            for k in range(hr_shifted.shape[0]):
                c[k] += hr_shifted[k, b] * v
    return c, math.sqrt(norm)


@kernel
def _translation_correlation(
    xy: np.ndarray, ang: np.ndarray, x: float, y: float, th: float, alpha: float, uv0: np.ndarray,
    nuv: np.ndarray, offsets: np.ndarray, huv: np.ndarray, tw: int, inv_bin: float,
) -> tuple[np.ndarray, np.ndarray, float, float, float, float]:
    """The translation correlations of :meth:`Localiser.correct`. The scan points ``xy`` (K, 2,
    robot frame) placed at ``(x, y, th)`` (ASR frame) and rotated by ``-alpha`` into the
    reference's main axes (u, v) fall into bins of ``1 / inv_bin`` m from ``uv0``, weighted on each
    axis by :func:`_axis_weight` (surface angles ``ang``, rad, robot frame). ``huv`` holds the
    reference's u and v histograms side by side, bin 0 of each at ``offsets``, each padded by the
    search window ``tw``, then a zero window: a point outside the reference's ``nuv`` bins goes
    there. Returns C_u(d) and C_v(d) = sum_b h_scan(b) h_ref(b + d),
    d = -tw..tw; the norms of the scan's u and v histograms; the sums of the points' u and v
    weights. Compiled (:mod:`mapper.jit`): it replaces a bincount and two windowed products."""
    n_h = huv.shape[0]
    out = n_h - 1 - tw
    h = np.zeros(n_h)
    cm, sm = math.cos(th - alpha), math.sin(th - alpha)
    ca, sa = math.cos(-alpha), math.sin(-alpha)
    org_u, org_v = ca * x - sa * y - uv0[0], sa * x + ca * y - uv0[1]
    wsum_u = wsum_v = 0.0
    for i in range(xy.shape[0]):
        bu = math.floor((xy[i, 0] * cm + xy[i, 1] * -sm + org_u) * inv_bin)
        bv = math.floor((xy[i, 0] * sm + xy[i, 1] * cm + org_v) * inv_bin)
        wu, wv = _axis_weight(ang[i] + th, alpha)
        wsum_u += wu
        wsum_v += wv
        h[bu + offsets[0] if 0 <= bu < nuv[0] else out] += wu
        h[bv + offsets[1] if 0 <= bv < nuv[1] else out] += wv
    split = offsets[1]
    width = 2 * tw + 1
    cu, cv = np.zeros(width), np.zeros(width)
    for r in range(split - tw):
        v = h[tw + r]
        if v != 0.0:
            for k in range(width):
                cu[k] += v * huv[r + k]
    for r in range(n_h - tw - split):
        v = h[split + r]
        if v != 0.0:
            for k in range(width):
                cv[k] += v * huv[split - tw + r + k]
    h[out] = 0.0
    norm_u = norm_v = 0.0
    for b in range(split):
        norm_u += h[b] * h[b]
    for b in range(split, n_h):
        norm_v += h[b] * h[b]
    return cu, cv, math.sqrt(norm_u), math.sqrt(norm_v), wsum_u, wsum_v


@kernel
def _densify(r: np.ndarray, w: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 2) and surface angles (N,) of a reference scan (points ``r`` in sweep order and
    their surface angles ``w``, NaN off surfaces), with points added every ``spacing`` metres between
    consecutive points less than ``_DENSE_GAP`` apart (one surface) at that chord's angle: first the
    scan's own points, then the added ones. Compiled (:mod:`mapper.jit`).

    A scan's points sample a wall every few centimetres, at other places than the reference's: the
    nearest reference *point* then pulls a point along the wall towards it, and ICP between the two
    samplings drifts (0.2° a viewpoint on a synthetic turn in place). Densified, the nearest point is
    about the nearest point on the wall."""
    n = r.shape[0]
    added = np.zeros(max(n - 1, 0), dtype=np.int64)  # per chord
    for i in range(n - 1):
        d = math.hypot(r[i + 1, 0] - r[i, 0], r[i + 1, 1] - r[i, 1])
        if d < _DENSE_GAP:
            added[i] = max(math.ceil(d / spacing) - 1, 0)
    total = n + added.sum()
    pts = np.empty((total, 2))
    ang = np.empty(total)
    pts[:n] = r
    ang[:n] = w
    at = n
    for i in range(n - 1):
        k = added[i]
        if k:
            dx, dy = r[i + 1, 0] - r[i, 0], r[i + 1, 1] - r[i, 1]
            a = math.atan2(dy, dx)
            for j in range(1, k + 1):
                f = j / (k + 1)
                pts[at, 0], pts[at, 1] = r[i, 0] + f * dx, r[i, 1] + f * dy
                ang[at] = a
                at += 1
    return pts, ang


@kernel
def _norm_peak(peak: float, norm_a: float, norm_b: float) -> float:
    """Normalised correlation peak (cosine similarity of the best-aligned histograms), 0..1."""
    den = norm_a * norm_b
    return peak / den if den > 0 else 0.0


@kernel
def _prominence(c: np.ndarray, i: int, bins: int, full: float) -> float:
    """How distinct the peak ``c[i]`` of a translation correlation ``c`` is, 0..1: 1 - (the largest
    value ``bins`` or more bins away from the peak) / (the peak), scaled so that ``full`` counts as 1.

    A histogram without structure along an axis (the walls of a corridor, seen along it) correlates
    almost equally at every shift: its cosine similarity is high, but its peak sits wherever the
    two point sets' extents overlap most, which drags the estimate back towards the reference."""
    peak = c[i]
    if peak <= 0.0:
        return 0.0
    lo, hi = c[: max(i - bins + 1, 0)], c[i + bins :]
    rest = max(lo.max() if len(lo) else 0.0, hi.max() if len(hi) else 0.0)
    return min(max((1.0 - rest / peak) / full, 0.0), 1.0)


@kernel
def _rotation_match(
    xy: np.ndarray, max_gap: float, th: float, hr_shifted: np.ndarray, hr_norm: float
) -> tuple[int, float, float, np.ndarray]:
    """Step 1 of :meth:`Localiser.correct` in one compiled call: the scan's :func:`_chords`
    (points ``xy`` (K, 2), robot frame), their :func:`_rotation_correlation` at the predicted
    heading ``th`` (rad) and its :func:`_peak`. Returns (the number of chord directions; the
    peak's shift from ``th`` in bins, parabola-refined; its quality q_theta, 0..1; the points'
    surface angles, rad, robot frame)."""
    dirs, ang = _chords(xy, max_gap)
    if dirs.shape[0] < 10:
        return dirs.shape[0], 0.0, 0.0, ang
    c, hc_norm = _rotation_correlation(dirs, th, hr_shifted)
    s, _, top = _peak(c)
    return dirs.shape[0], s - (c.shape[0] - 1) / 2.0, _norm_peak(top, hc_norm, hr_norm), ang


@kernel
def _translation_match(
    xy: np.ndarray, ang: np.ndarray, x: float, y: float, th: float, alpha: float, uv0: np.ndarray,
    nuv: np.ndarray, offsets: np.ndarray, huv: np.ndarray, tw: int, inv_bin: float,
    ref_norm_u: float, ref_norm_v: float, info_full: float, prom_bins: int, prom_full: float,
) -> tuple[float, float, float, float]:
    """Step 2 of :meth:`Localiser.correct` in one compiled call: the
    :func:`_translation_correlation` of the scan at (x, y, th) (ASR frame), the :func:`_peak` of
    each axis and its quality: normalised peak times :func:`_prominence` times how much the
    scan's surfaces face that axis (an axis few surfaces face, the along-corridor one, counts only
    as much as they are there). Returns (the u and v shifts in bins, parabola-refined; q_u, q_v,
    0..1)."""
    cu, cv, norm_u, norm_v, info_u, info_v = _translation_correlation(
        xy, ang, x, y, th, alpha, uv0, nuv, offsets, huv, tw, inv_bin)
    su, iu, top_u = _peak(cu)
    sv, iv, top_v = _peak(cv)
    full = xy.shape[0] * info_full
    q_u = (_norm_peak(top_u, norm_u, ref_norm_u) * _prominence(cu, iu, prom_bins, prom_full)
           * min(max(info_u / full, 0.0), 1.0))
    q_v = (_norm_peak(top_v, norm_v, ref_norm_v) * _prominence(cv, iv, prom_bins, prom_full)
           * min(max(info_v / full, 0.0), 1.0))
    return su - tw, sv - tw, q_u, q_v


_I3 = np.eye(3)


def _kalman_predict(
    x: np.ndarray, p: np.ndarray, u: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """filterpy's ``KalmanFilter.predict(u, Q=q)`` with F = B = I (state ``x``: ASR frame, m, m,
    rad; covariance ``p``), without its calls and copies: the same floating-point results bit for
    bit. A product with I gives each entry plus 0.0 (a -0.0 becomes +0.0), hence the ``+ 0.0``."""
    return (x + 0.0) + (u + 0.0), (p + 0.0) + q


def _kalman_update(
    x: np.ndarray, p: np.ndarray, z: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """filterpy's functional ``update(x, P, z, R, H)`` with H = I (the measured pose ``z`` and
    state ``x`` in the ASR frame, m, m, rad; covariances ``p``, ``r``): its arithmetic in its
    order (Joseph form), without the products with H, which only add 0.0 to each entry (``+ 0.0``
    keeps even a -0.0 as they leave it): the same results bit for bit, in half the time."""
    hp = p + 0.0  # H P H^T and P H^T
    k = np.dot(hp, np.linalg.inv(hp + r))
    x = x + np.dot(k, z - (x + 0.0))
    i_kh = _I3 - (k + 0.0)
    return x, np.dot(np.dot(i_kh, p), i_kh.T) + np.dot(np.dot(k, r), k.T)


def _mahalanobis2(y: np.ndarray, s: np.ndarray) -> float:
    """y^T S^-1 y for a 3-vector and a symmetric positive definite 3x3 S (closed form, no LAPACK call)."""
    (a, b, c), (_, d, e), (_, _, f) = s.tolist()  # Python floats: the same arithmetic, faster
    # cofactors of the symmetric matrix [[a b c] [b d e] [c e f]]
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A + b * B + c * C
    if det <= 0:
        return math.inf
    y0, y1, y2 = y.tolist()
    q = A * y0 * y0 + D * y1 * y1 + F * y2 * y2 + 2 * (B * y0 * y1 + C * y0 * y2 + E * y1 * y2)
    return float(q / det)
