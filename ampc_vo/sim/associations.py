"""Cross-camera associations a frontend could measure: no truth leaks (issue 13).

The simulator knows which landmark every track sees; handing those ids to the estimator as
cross-camera matches (``CameraObservations.landmark_ids``) would give it an ideal appearance matcher
between cameras that never see the same thing at the same time. A frontend finds cross-camera
matches only where two cameras of one body **overlap** (stereo matching in the same frame, as
``frontend.stereo`` does on KITTI). So:

1. :func:`overlapping_pairs`: two cameras overlap if they sit on the same body and at least
   ``min_fraction`` of the rays of the first, sampled on an image grid at depths within the
   simulated range, project into the second (a geometric test of the frustums, independent of the
   landmarks);
2. :func:`association_ids`: in each frame, an inlier track seen by two or more overlapping cameras
   of one group gets the track id of its first camera (rig order) as association id in all of them,
   as a stereo matcher labels the second image's features with the first's; every other row gets
   -1 (unknown). Outliers are never associated.
"""
from __future__ import annotations

import numpy as np

from ampc_vo.geometry import invert_pose
from ampc_vo.rig import Rig

__all__ = ["overlapping_pairs", "overlap_groups", "association_ids"]

_GRID = (16, 12)
_DEPTHS_M = (2.0, 4.0, 8.0, 16.0, 32.0)


def overlap_fraction(rig: Rig, first: str, second: str, max_range_m: float = 60.0) -> float:
    """Fraction of ``first``'s sampled rays (image grid x depths up to ``max_range_m``) that
    ``second`` sees; 0 for cameras on different bodies (their relative pose changes)."""
    camera_a, camera_b = rig.camera(first), rig.camera(second)
    if camera_a.body != camera_b.body:
        return 0.0
    u = (np.arange(_GRID[0]) + 0.5) * camera_a.width / _GRID[0] - 0.5
    v = (np.arange(_GRID[1]) + 0.5) * camera_a.height / _GRID[1] - 0.5
    pixels = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
    rays = camera_a.unproject(pixels)
    depths = np.array([depth for depth in _DEPTHS_M if depth <= max_range_m] or [max_range_m])
    points_a = (rays[None, :, :] * depths[:, None, None]).reshape(-1, 3)
    T_b_a = invert_pose(camera_b.T_body_camera) @ camera_a.T_body_camera
    points_b = points_a @ T_b_a[:3, :3].T + T_b_a[:3, 3]
    _, valid = camera_b.project(points_b)
    return float(np.mean(valid))


def overlapping_pairs(rig: Rig, max_range_m: float = 60.0, min_fraction: float = 0.05) -> list[tuple[str, str]]:
    """Camera pairs (rig order) whose views overlap (module docstring, step 1)."""
    names = rig.camera_names
    return [(a, b) for i, a in enumerate(names) for b in names[i + 1:]
            if max(overlap_fraction(rig, a, b, max_range_m), overlap_fraction(rig, b, a, max_range_m)) >= min_fraction]


def overlap_groups(rig: Rig, max_range_m: float = 60.0, min_fraction: float = 0.05) -> np.ndarray:
    """(C,) group label per rig camera: cameras connected by overlapping pairs share a label."""
    names = list(rig.camera_names)
    label = np.arange(len(names))
    for a, b in overlapping_pairs(rig, max_range_m, min_fraction):
        old, new = label[names.index(b)], label[names.index(a)]
        label[label == old] = new
    return label


def association_ids(frame: np.ndarray, camera_index: np.ndarray, landmark_id: np.ndarray, track_id: np.ndarray,
                    is_outlier: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """(M,) association ids of measurement rows (module docstring, step 2), -1 where unknown."""
    result = np.full(len(frame), -1, np.int64)
    candidate = np.flatnonzero(~is_outlier)
    if candidate.size == 0:
        return result
    group = groups[camera_index[candidate]]
    # Rows of one (frame, group, landmark) are one physical point seen by overlapping cameras.
    keys = np.stack([frame[candidate], group, landmark_id[candidate]], axis=1)
    order = np.lexsort((camera_index[candidate], keys[:, 2], keys[:, 1], keys[:, 0]))
    sorted_keys = keys[order]
    start = np.ones(len(order), bool)
    start[1:] = np.any(sorted_keys[1:] != sorted_keys[:-1], axis=1)
    run = np.cumsum(start) - 1
    sizes = np.bincount(run)
    first_row = candidate[order][start]                       # first camera (rig order) of each run
    shared = sizes[run] >= 2
    rows = candidate[order][shared]
    result[rows] = track_id[first_row[run[shared]]]
    return result
