"""Dataset readers and writers: our folder format (DESIGN section 5) and, later, KITTI odometry."""
from ampc_vo.datasets.folder import (
    FRAMES_FILE,
    GROUNDTRUTH_COLUMNS,
    GROUNDTRUTH_FILE,
    RIG_FILE,
    Dataset,
    decode_image,
    image_relative_path,
    read_dataset,
    write_dataset,
)

__all__ = [
    "FRAMES_FILE", "GROUNDTRUTH_COLUMNS", "GROUNDTRUTH_FILE", "RIG_FILE", "Dataset", "decode_image",
    "image_relative_path", "read_dataset", "write_dataset",
]
