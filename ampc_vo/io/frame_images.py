"""Loading all cameras' images of one frame, tolerant of missing or corrupt files."""
from __future__ import annotations

import logging
import numpy as np

from ampc_vo.errors import DatasetError

logger = logging.getLogger(__name__)


def load_frame_images(dataset: "object", frame: int) -> dict[str, np.ndarray | None]:
    """All cameras' images of one frame; a missing or corrupt image becomes ``None`` with a warning
    (``dataset`` has ``camera_names`` and ``load_image(frame, camera)``: our folder format or KITTI;
    the tracker of that camera re-initialises; the run goes on)."""
    images: dict[str, np.ndarray | None] = {}
    for camera in dataset.camera_names:
        try:
            images[camera] = dataset.load_image(frame, camera)
        except DatasetError as error:
            logger.warning("frame %d: %s; camera %s skipped", frame, error, camera)
            images[camera] = None
    return images
