"""Reading a frame's camera images (``ampc_vo.io.frame_images``): decoded in parallel threads and one
frame ahead, with the same images, the same warnings in the same order and the same errors as
reading them one after another."""
from __future__ import annotations

import logging
import threading

import numpy as np
import pytest

from ampc_vo.errors import DatasetError
from ampc_vo.io.folder import read_dataset
from ampc_vo.io.frame_images import FrameImageReader, load_frame_images, read_frame_images


@pytest.fixture
def damaged(tiny_dataset):
    """The tiny dataset (5 frames, 4 cameras) with a missing image (frame 2, left) and a corrupt one
    (frame 2, rear)."""
    (tiny_dataset / "images" / "left" / "000002.png").unlink()
    (tiny_dataset / "images" / "rear" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    return read_dataset(tiny_dataset, allow_missing_images=True)


def _skipped(caplog) -> list[str]:
    return [record.getMessage() for record in caplog.records if "skipped" in record.getMessage()]


def test_parallel_and_read_ahead_give_the_images_and_warnings_of_reading_in_turn(damaged, caplog):
    with caplog.at_level(logging.WARNING):
        in_turn = [load_frame_images(damaged, frame) for frame in range(len(damaged))]
        expected = _skipped(caplog)
        caplog.clear()
        with FrameImageReader(damaged, range(len(damaged)), threads=3) as reader:
            ahead = [reader.take(frame).images for frame in range(len(damaged))]
    assert len(expected) == 2 and "000002.png: image file missing" in expected[0] and "camera left skipped" in expected[0]
    assert "cannot be decoded" in expected[1] and "camera rear skipped" in expected[1]
    assert _skipped(caplog) == expected  # same messages, same (camera) order
    for old, new in zip(in_turn, ahead):
        assert list(old) == list(new) == list(damaged.camera_names)
        for camera in old:
            assert (old[camera] is None) == (new[camera] is None)
            if old[camera] is not None:
                np.testing.assert_array_equal(old[camera], new[camera])


def test_a_frames_problems_are_logged_when_it_is_taken_not_when_it_is_read_ahead(damaged, caplog):
    with caplog.at_level(logging.WARNING), FrameImageReader(damaged, range(len(damaged)), threads=2) as reader:
        reader.take(1)  # starts reading frame 2 (the damaged one)
        reader._ahead[1].result()  # read, not yet taken
        assert _skipped(caplog) == []
        assert reader.take(2).images["left"] is None
        assert len(_skipped(caplog)) == 2


def test_frames_taken_out_of_order_are_read_then(damaged):
    with FrameImageReader(damaged, range(len(damaged)), threads=2) as reader:
        np.testing.assert_array_equal(reader.take(4).images["front"], damaged.load_image(4, "front"))
        np.testing.assert_array_equal(reader.take(0).images["front"], damaged.load_image(0, "front"))


class _FailingDataset:
    """Two cameras; frame 1 cannot be read at all (an unexpected error, not a bad image)."""

    camera_names = ("a", "b")

    def load_image(self, frame: int, camera: str) -> np.ndarray:
        if frame == 1:
            raise OSError("disk gone")
        return np.full((4, 4), frame, np.uint8)


def test_an_unexpected_error_is_raised_for_its_own_frame(caplog):
    with FrameImageReader(_FailingDataset(), range(3), threads=2) as reader:
        assert reader.take(0).images["a"][0, 0] == 0  # frame 1's error is read ahead, not raised here
        with pytest.raises(OSError, match="disk gone"):
            reader.take(1)


class _OneFileDataset:
    """Like a recording: ``fetch_frame`` reads a frame from one file (here: notes the thread), then
    ``load_image`` decodes; frame 3's fetch fails."""

    camera_names = ("a", "b", "c")

    def __init__(self) -> None:
        self.fetching_threads: set[str] = set()
        self.loading_threads: dict[int, set[str]] = {}

    def fetch_frame(self, frame: int) -> None:
        self.fetching_threads.add(threading.current_thread().name)
        if frame == 3:
            raise DatasetError(f"frame {frame}: cannot read its images")

    def load_image(self, frame: int, camera: str) -> np.ndarray:
        self.loading_threads.setdefault(frame, set()).add(threading.current_thread().name)
        if frame == 3:
            raise DatasetError(f"frame {frame}: cannot read its images")
        return np.full((4, 4), frame, np.uint8)


def test_a_dataset_read_from_one_file_is_fetched_in_one_thread_and_falls_back_to_reading_in_turn(caplog):
    dataset = _OneFileDataset()
    with caplog.at_level(logging.WARNING), FrameImageReader(dataset, range(5), threads=3) as reader:
        for frame in range(5):
            reader.take(frame)
    assert len(dataset.fetching_threads) == 1 and next(iter(dataset.fetching_threads)).startswith("frame-reader")
    assert dataset.loading_threads[3] == dataset.fetching_threads  # the failed fetch: each camera in turn, in the reading thread
    assert _skipped(caplog) == [f"frame 3: frame 3: cannot read its images; camera {camera} skipped" for camera in "abc"]


def test_read_frame_images_without_a_decoder_reads_in_this_thread(damaged):
    read = read_frame_images(damaged, 2)
    assert read.frame == 2 and set(read.problems) == {"left", "rear"} and read.images["front"] is not None
