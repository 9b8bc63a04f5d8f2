"""Plausibility of frame timestamps where they enter (frames.csv, KITTI times.txt, measurements.npz; issue 14).

Timestamps are seconds. A camera runs at about 1 to 1000 frames per second, so the median frame
interval of a sequence lies between :data:`MIN_INTERVAL_S` and :data:`MAX_INTERVAL_S`; outside, the
unit is wrong (milliseconds or nanoseconds give intervals 10^3 or 10^9 times too long: every
speed and the hitch rate come out that much too small) and the input is refused with the likely
unit. A single interval far longer than the median (dropped frames, a recording paused) is
allowed with a warning: the tracks are lost there and the motion across the gap is not measured.
"""
from __future__ import annotations

import logging

import numpy as np

from ampc_vo.errors import DatasetError

logger = logging.getLogger(__name__)

MIN_INTERVAL_S = 1e-4  # 10 000 frames per second
MAX_INTERVAL_S = 10.0  # one frame per 10 s
GAP_FACTOR = 10.0  # an interval this many times the median (and over GAP_MIN_S) is a gap
GAP_MIN_S = 1.0
_UNITS = (("milliseconds", 1e-3), ("microseconds", 1e-6), ("nanoseconds", 1e-9))


def check_frame_times(timestamps: np.ndarray, where: str, line_offset: int = 0) -> None:
    """:class:`DatasetError` naming ``where`` when the median interval of ``timestamps`` (finite,
    strictly increasing: checked by the caller) is no camera's (module docstring); a warning for
    each gap. ``line_offset``: the file line of ``timestamps[0]`` (0: say "frame")."""
    timestamps = np.asarray(timestamps, dtype=float)
    if timestamps.size < 2:
        return
    intervals = np.diff(timestamps)
    median = float(np.median(intervals))
    if median > MAX_INTERVAL_S:
        guess = next((f" (in {unit}? then it is {median * factor:.3g} s)" for unit, factor in _UNITS if MIN_INTERVAL_S <= median * factor <= MAX_INTERVAL_S), "")
        raise DatasetError(f"{where}: median frame interval {median:.6g} s, longer than any camera's ({MAX_INTERVAL_S:g} s): "
                           f"timestamps must be in seconds{guess}")
    if median < MIN_INTERVAL_S:
        raise DatasetError(f"{where}: median frame interval {median:.3g} s, shorter than any camera's ({MIN_INTERVAL_S:g} s): timestamps must be in seconds")
    for index in np.flatnonzero(intervals > max(GAP_FACTOR * median, GAP_MIN_S)):
        at = f"line {int(index) + line_offset + 1}" if line_offset else f"frame {int(index) + 1}"
        logger.warning("%s: %s comes %.3g s after the previous frame (median interval %.3g s): the tracks are lost there "
                       "and the motion across the gap is not measured", where, at, intervals[index], median)
