"""How well a calibrated puppet skeleton fixes each bone's direction in a new pose
(:attr:`~stillcap.body.puppet_calibrate.SkeletonCalibration.direction_sd_deg`).

The joint fit of :func:`~stillcap.body.puppet_calibrate.calibrate_skeleton` gives the covariance
of the calibrated body (bone scales and bead offsets, correlated). Its error shows in a pose only
where the pose moves the beads along the directions the captures left open: a joint that no
capture bends can slide along its bone with its beads' offsets moved back, and every capture
(the rest pose included) is explained as well, but a pose that bends it is not. So the body's
covariance is carried through the fit of a *new* pose, here a fixed set of probe poses with every
joint anywhere within the template's limits (the assumption stated: a pose to be captured is
one of those), and not only through the captures' own poses (which bend exactly the joints the
captures fix: on ``another_puppet`` seed 12 they predicted 0.085 deg for an ``upper-back`` that
came out 1.74 deg off in a test pose, the ``lower-back`` joint 1.0 mm off with a 1.15 mm sd).
"""
from __future__ import annotations

import numpy as np

from stillcap.body.skeleton import EULER_LIMIT_SEQUENCE, Skeleton, forward_kinematics

__all__ = ["PROBE_POSES", "WEAK_POSE_RATIO", "direction_sd_in_captures", "new_pose_direction_sd",
           "new_pose_direction_var", "probe_local_rotations", "weakly_posed_bones"]

#: Probe poses over which :attr:`SkeletonCalibration.direction_sd_deg` is the RMS (drawn once,
#: seeded: the prediction is a function of the calibration alone).
PROBE_POSES = 16


def probe_local_rotations(template: Skeleton, n: int = PROBE_POSES, seed: int = 0) -> np.ndarray:
    """``n`` poses with every joint's intrinsic XYZ Euler angles uniform within the template's
    limits (:func:`~stillcap.body.retarget.euler_bounds_deg`; the root at rest), shape
    (n, n_joints, 3, 3). No collision test: a probe only needs the joints bent as a pose may bend
    them."""
    from scipy.spatial.transform import Rotation

    from stillcap.body.retarget import euler_bounds_deg

    b = euler_bounds_deg(template)
    ang = np.random.default_rng(seed).uniform(b[..., 0], b[..., 1], size=(n,) + b.shape[:-1])
    ang[:, template.root] = 0.0
    return Rotation.from_euler(EULER_LIMIT_SEQUENCE, ang.reshape(-1, 3), degrees=True).as_matrix().reshape(
        n, template.n_joints, 3, 3)


def new_pose_direction_var(skeleton: Skeleton, template_offsets: np.ndarray, frames: np.ndarray,
                           beads_m: np.ndarray, bones: list[int], cov_body: np.ndarray, local_rotations: np.ndarray,
                           sigma_m: np.ndarray) -> np.ndarray:
    """Variance of each bone's unit direction (rad^2, summed over its 3 components) in a pose
    with these local rotations fitted with the calibrated body, shape (len(bones),).

    As :func:`direction_sd_in_captures` for a capture: the pose's unknowns
    ``r`` (root position, and every joint's rotation as a small turn about its free axes: all
    three where the template leaves all three free, else its free Euler axes' own axes are
    approximated by the joint's local axes) are fitted to every bead at ``sigma_m`` with the
    body ``b`` held, so ``cov(r) = A cov(b) A^T + inv(J_r^T J_r)``, ``A = -inv(J_r^T J_r) J_r^T J_b``,
    plus a 180 deg prior on each turn (a turn no bead fixes). Derivatives are analytic: a bead
    moves with ``W_frame`` for its offset, with ``W_parent(k) c_k`` for bone ``k``'s scale on its
    path, and with ``w x (p - joint)`` for a small turn ``w`` of a joint on its path.

    ``skeleton``: the calibrated skeleton (its offsets); ``template_offsets``: the template's
    offsets ``c`` the scales multiply, (n_joints, 3), metres; ``frames``: each bead's bone frame;
    ``beads_m``: bead offsets in their frames, (n_markers, 3); ``bones``: the scaled bones, in the
    order of ``cov_body``'s first ``len(bones)`` rows (then the bead offsets, 3 per bead);
    ``sigma_m``: each bead's error per axis, metres."""
    nm, nj = len(frames), skeleton.n_joints
    parents, root = skeleton.parents, skeleton.root
    lim = skeleton.limits_deg
    free = ~(np.isfinite(lim[..., 0]) & np.isfinite(lim[..., 1]) & (lim[..., 1] <= lim[..., 0]))
    free[root] = True
    j2w = forward_kinematics(skeleton, np.eye(4), local_rotations)
    R, o = j2w[:, :3, :3], j2w[:, :3, 3]
    pts = np.einsum("nij,nj->ni", R[frames], beads_m) + o[frames]
    on_path = np.zeros((nm, nj), bool)  # joint k moves bead m
    for m, f in enumerate(frames):
        k = f
        while k >= 0:
            on_path[m, k] = True
            k = parents[k]
    n_s = len(bones)
    w = 1.0 / np.repeat(np.asarray(sigma_m, float), 3)
    Jb = np.zeros((3 * nm, n_s + 3 * nm))
    for i, k in enumerate(bones):
        Jb[:, i] = (on_path[:, k, None] * (R[parents[k]] @ template_offsets[k])).ravel()
    for m, f in enumerate(frames):
        Jb[3 * m:3 * m + 3, n_s + 3 * m:n_s + 3 * m + 3] = R[f]
    # the pose's unknowns: root position, then (joint, world axis) small turns on free axes
    axes = [(k, a) for k in range(nj) for a in range(3) if free[k, a]]
    Jr = np.zeros((3 * nm, 3 + len(axes)))
    Jr[:, :3] = np.tile(np.eye(3), (nm, 1))
    G = np.zeros((len(bones), 3, 3 + len(axes)))
    dirs = np.stack([R[parents[k]] @ skeleton.offsets[k] / np.linalg.norm(skeleton.offsets[k]) for k in bones])
    for q, (k, a) in enumerate(axes):
        axis = R[k][:, a]  # a small turn about the joint's local axis a, in the world
        moved = on_path[:, k]
        Jr[:, 3 + q] = (np.cross(axis, pts - o[k]) * moved[:, None]).ravel()
        for i, b in enumerate(bones):
            j = parents[b]
            while j >= 0 and j != k:
                j = parents[j]
            if j == k:
                G[i, :, 3 + q] = np.cross(axis, dirs[i])
    Jb, Jr = Jb * w[:, None], Jr * w[:, None]
    H = Jr.T @ Jr
    H[3:, 3:] += np.eye(len(axes)) / np.pi ** 2
    own = np.linalg.pinv(H)
    A = -own @ (Jr.T @ Jb)
    C = A @ cov_body @ A.T + own
    return np.einsum("bip,pq,biq->b", G, C, G)


def new_pose_direction_sd(skeleton: Skeleton, template_offsets: np.ndarray, frames: np.ndarray, beads_m: np.ndarray,
                          bones: list[int], jac, misfit: float, sigmas: list, n_probes: int = PROBE_POSES
                          ) -> dict[int, float]:
    """Bone index -> predicted RMS direction error in a new pose, degrees, over ``n_probes``
    probe poses (:func:`probe_local_rotations`): the joint fit's ``inv(J^T J)`` (``jac``, its
    residuals in sigmas; the body its first ``len(bones) + 3 * n_markers`` unknowns) widened by
    ``misfit`` when above 1, each bead at its median expected error over the captures
    (``sigmas``, metres), through :func:`new_pose_direction_var`."""
    J = jac.toarray() if hasattr(jac, "toarray") else np.asarray(jac)
    n_body = len(bones) + 3 * len(frames)
    cov = np.linalg.pinv(J.T @ J)[:n_body, :n_body] * max(float(misfit) if np.isfinite(misfit) else 1.0, 1.0)
    sigma = np.median(np.vstack(sigmas), axis=0)
    var = np.mean([new_pose_direction_var(skeleton, template_offsets, frames, beads_m, bones, cov, local, sigma)
                   for local in probe_local_rotations(skeleton, n_probes)], axis=0)
    return {k: float(np.degrees(np.sqrt(v))) for k, v in zip(bones, var)}


#: :func:`weakly_posed_bones`: a bone is weakly posed when its predicted error in a new pose is
#: over this many times its error in the captures' own poses (the captures explain the beads
#: where their joints are, not where a new pose bends them).
WEAK_POSE_RATIO = 2.0


def weakly_posed_bones(template: Skeleton, captures_sd_deg: dict, new_sd_deg: dict) -> dict[str, str]:
    """Bones whose direction the captures' poses fix much better than a new pose would, with the
    capture that would fix them: new-pose error over :data:`WEAK_POSE_RATIO` times the captures'
    and its 95 % bound (1.96 sigma) over the per-bone checks' tolerance
    (:data:`~stillcap.body.puppet_checks.BONE_TOLERANCE_DEG`: a check of the next capture could
    name it). A bone's direction is its start joint's frame, pivoting at that joint: the joint's
    place along the spine or limb is what the captures leave open when none bends it."""
    from stillcap.body.puppet_checks import BONE_TOLERANCE_DEG

    out = {}
    for name, sd in new_sd_deg.items():
        was = captures_sd_deg.get(name, float("nan"))
        if not (sd > WEAK_POSE_RATIO * was and 1.96 * sd > BONE_TOLERANCE_DEG):
            continue
        parent = template.names[template.parents[template.index(name)]]
        out[name] = (f"the {parent} -> {name} direction is weakly fixed by the poses given: {was:.2f} deg "
                     f"predicted in their poses, {sd:.2f} deg in a new pose (the captures do not bend {parent} "
                     f"enough to place it along its bone); add a capture (--pose) with {parent} and {name} bent "
                     f"well away from rest and from the other captures")
    return out


def direction_sd_in_captures(res, n_data: int, fk, cap_slice, n_caps: int, bones: list[int], template: Skeleton,
                             c: np.ndarray, n_v: int, data_rows, n_body: int, prior_row0: int, n_a: int,
                             whole: list) -> tuple[dict[int, float], float]:
    """Predicted direction error of each bone in the poses of the joint fit's further captures
    fitted again with the calibrated skeleton, radians, and the fit's misfit (chi-square of the
    beads per degree of freedom).

    Each further capture stands in for a new pose (it bends only the joints the captures bend:
    :func:`new_pose_direction_sd` carries the same covariance through probe poses). A new pose's
    rotations ``r`` are fitted to its beads with the calibrated body ``b`` (bone scales and bead offsets, the joint fit's first
    ``n_body`` unknowns) held, so their error is the body's error carried through that fit plus the
    pose's own fit noise, independent of each other::

        cov(r) = A cov(b) A^T + inv(J_r^T J_r),   A = -inv(J_r^T J_r) J_r^T J_b

    (``J_r``, ``J_b``: the Jacobian of the capture's bead residuals and its rotations' weak prior in
    its rotations and the body;
    ``cov(b)``: the joint fit's ``inv(J^T J)``), carried to each bone's world direction (finite
    differences over the capture's rotations), RMS over the captures that saw every bead of the
    bone's parent frame (``whole[p]``: the bones so seen in capture ``p``; a bead missing there is
    not what a new pose with all beads seen would show; all captures when none did). The residuals are in sigmas
    of each bead's expected error, so the prediction is as honest as those errors; a misfit above
    1 (the beads scatter more than expected) widens it."""
    if n_caps < 2:
        return {}, float("nan")
    J = res.jac.toarray() if hasattr(res.jac, "toarray") else np.asarray(res.jac)
    cov = np.linalg.pinv(J.T @ J)
    Jd = J[:n_data]
    hat = float(np.sum((Jd @ cov) * Jd))  # parameters the data (not the priors) fix
    r = res.fun[:n_data]
    misfit = float(r @ r) / max(n_data - hat, 1.0)
    inflate = max(misfit, 1.0)
    cov_b = cov[:n_body, :n_body]
    parents = template.parents
    var = {k: [] for k in bones}
    for p in range(1, n_caps):
        b, e, end = cap_slice(p)

        def directions(xx, p=p):
            j2w = fk(xx, p)
            return np.stack([j2w[parents[k], :3, :3] @ (c[k] / np.linalg.norm(c[k])) for k in bones])

        d0 = directions(res.x)
        G = np.zeros((len(bones), 3, end - b))
        for q in range(e - b, end - b):
            step = 1e-6 if q - (e - b) < n_v else 1e-4  # radians (rotation vectors), degrees (Euler angles)
            xx = res.x.copy()
            xx[b + q] += step
            G[:, :, q] = (directions(xx) - d0) / step
        # the capture's bead rows and its rotations' weak prior (a turn no bead fixes, such as a
        # one-bead frame's twist, keeps the prior's 180 deg instead of none)
        rows = np.r_[data_rows[p]:data_rows[p + 1], prior_row0 + (p - 1) * n_a:prior_row0 + p * n_a]
        Jr, Jb = J[rows, b:end], J[rows, :n_body]
        own = np.linalg.pinv(Jr.T @ Jr)
        A = -own @ (Jr.T @ Jb)
        C = (A @ cov_b @ A.T + own) * inflate
        for i, k in enumerate(bones):
            var[k].append((k in whole[p], float(np.trace(G[i] @ C @ G[i].T))))

    def rms(v):
        seen_all = [x for w, x in v if w]
        return float(np.sqrt(np.mean(seen_all or [x for _, x in v])))

    return {k: rms(v) for k, v in var.items()}, misfit
