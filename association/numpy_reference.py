"""A straightforward loop implementation of the Joint Cloud (OpenCV + NumPy): the test oracle and the
benchmark's baseline for :func:`association.build_joint_cloud`."""

from __future__ import annotations

import itertools

import cv2
import numpy as np

import geometry

from ._joint_cloud import JointCloudConfig

__all__ = ["numpy_joint_cloud_frame"]


def numpy_joint_cloud_frame(
    rig: geometry.Camera, xy: np.ndarray, score: np.ndarray, mask: np.ndarray, config: JointCloudConfig = JointCloudConfig()
) -> list[dict]:
    """The valid candidates of one frame as a list of dicts (loops over pairs, joints, candidates).

    ``xy (V, J, C, 2)`` observed pixels, ``score``, ``mask`` ``(V, J, C)``. Each dict holds ``pair``,
    ``joint``, ``a``, ``b`` (grid position), ``point`` (metres), ``ray_distance`` (metres) and
    ``reprojection_error`` (pixels, two views). Triangulation by ``cv2.triangulatePoints`` on
    ``cv2.undistortPoints`` pixels.
    """
    K, R, t, dist = (np.asarray(a, np.float64) for a in (rig.K, rig.R, rig.t, rig.dist))
    num_views, num_joints, num_candidates = mask.shape
    projections = np.einsum("vij,vjk->vik", K, np.concatenate([R, t[:, :, None]], axis=2))
    centres = -np.einsum("vji,vj->vi", R, t)
    out = []
    for p, (va, vb) in enumerate(itertools.combinations(range(num_views), 2)):
        for j in range(num_joints):
            for a in range(num_candidates):
                for b in range(num_candidates):
                    if not (mask[va, j, a] and mask[vb, j, b]):
                        continue
                    if score[va, j, a] <= config.min_score or score[vb, j, b] <= config.min_score:
                        continue
                    pix, rays = [], []
                    for v, c in ((va, a), (vb, b)):
                        raw = np.asarray(xy[v, j, c], np.float64).reshape(1, 1, 2)
                        pix.append(cv2.undistortPoints(raw, K[v], dist[v], P=K[v]).reshape(2))
                        norm = cv2.undistortPoints(raw, K[v], dist[v]).reshape(2)
                        rays.append(R[v].T @ np.array([norm[0], norm[1], 1.0]))
                    normal = np.cross(rays[0], rays[1])
                    ray_distance = abs(np.dot(centres[vb] - centres[va], normal)) / np.linalg.norm(normal)
                    if ray_distance >= config.max_ray_distance:
                        continue
                    h = cv2.triangulatePoints(projections[va], projections[vb], pix[0].reshape(2, 1), pix[1].reshape(2, 1))
                    point = h[:3, 0] / h[3, 0]
                    homogeneous = np.append(point, 1.0)
                    errors, depths = [], []
                    for v, px in ((va, pix[0]), (vb, pix[1])):
                        proj = projections[v] @ homogeneous
                        depths.append(proj[2])
                        errors.append(np.linalg.norm(proj[:2] / proj[2] - px))
                    if min(depths) <= 0:
                        continue
                    out.append({"pair": p, "joint": j, "a": a, "b": b, "point": point,
                                "ray_distance": ray_distance, "reprojection_error": np.array(errors)})
    return out
