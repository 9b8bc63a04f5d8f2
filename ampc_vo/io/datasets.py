"""One entry to the ground truth of any dataset format we read: the dataset folder or KITTI."""
from __future__ import annotations

from pathlib import Path

from ampc_vo.errors import DatasetError
from ampc_vo.io.folder import read_dataset
from ampc_vo.io.groundtruth import GroundTruth, groundtruth_of
from ampc_vo.io.kitti import is_kitti_folder, load_kitti_truth


def load_groundtruth(dataset_dir: str | Path) -> GroundTruth:
    """Ground truth of a dataset folder (DESIGN section 5), read by :func:`ampc_vo.io.folder.read_dataset`,
    or of a KITTI odometry folder (recognised by its files; :func:`ampc_vo.io.kitti.load_kitti_truth`:
    the body poses, compared in KITTI's left-camera frame through ``T_tractor_reference``)."""
    if is_kitti_folder(dataset_dir):
        return load_kitti_truth(dataset_dir)

    truth = groundtruth_of(read_dataset(dataset_dir, load_measurements_file=False, image_files=False))
    if truth is None:
        raise DatasetError(f"{dataset_dir}: dataset has no groundtruth.csv")
    return truth


