"""Data formats (DESIGN section 5): our dataset folder, ``measurements.npz``, ground truth, KITTI
odometry folders, the run outputs (TUM trajectories, hitch.csv). Every reader validates where the
data enters and raises :class:`~ampc_vo.errors.DatasetError`."""
