"""Tests of ampc_vo.io.outputs: incremental writers and readers of tractor.tum, trailer.tum, hitch.csv."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.errors import DatasetError, OutputError
from ampc_vo.geometry import make_pose, rot_x, rot_z
from ampc_vo.io.outputs import HITCH_FILE, TRACTOR_FILE, TRAILER_FILE, OutputWriter, Trajectory, read_hitch, read_tum, write_tum


def _random_poses(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.array([make_pose(rot_z(rng.uniform(-3, 3)) @ rot_x(rng.uniform(-0.1, 0.1)), rng.normal(size=3) * 50) for _ in range(count)])


def test_round_trip(tmp_path):
    tractor, trailer = _random_poses(5, 1), _random_poses(5, 2)
    stamps = np.arange(5) * 0.1 + 1000.0
    with OutputWriter(tmp_path) as writer:
        for k in range(5):
            writer.write(stamps[k], tractor[k], trailer[k], 0.1 * k, 0.01 if k else None)
    read_tractor, read_trailer = read_tum(tmp_path / TRACTOR_FILE), read_tum(tmp_path / TRAILER_FILE)
    np.testing.assert_allclose(read_tractor.timestamps, stamps, atol=1e-6)
    np.testing.assert_allclose(read_tractor.poses, tractor, atol=1e-8)
    np.testing.assert_allclose(read_trailer.poses, trailer, atol=1e-8)
    hitch = read_hitch(tmp_path / HITCH_FILE)
    np.testing.assert_allclose(hitch.angles, 0.1 * np.arange(5), atol=1e-9)
    assert np.isnan(hitch.sigmas[0]) and hitch.sigmas[1] == pytest.approx(0.01)


def test_rows_survive_a_crash(tmp_path):
    """Each row is flushed: a crash inside the with-block keeps the rows written before it."""
    poses = _random_poses(3)
    with pytest.raises(RuntimeError):
        with OutputWriter(tmp_path) as writer:
            for k in range(3):
                writer.write(float(k), poses[k], poses[k], 0.0, 0.1)
            # read while still open (the process could die here)
            assert len(read_tum(tmp_path / TRACTOR_FILE)) == 3
            assert len(read_hitch(tmp_path / HITCH_FILE)) == 3
            raise RuntimeError("simulated crash")
    assert len(read_tum(tmp_path / TRAILER_FILE)) == 3


def test_tractor_only_writes_one_file(tmp_path):
    with OutputWriter(tmp_path, with_trailer=False) as writer:
        writer.write(0.0, np.eye(4), np.eye(4), 0.1, 0.1)
    assert (tmp_path / TRACTOR_FILE).is_file()
    assert not (tmp_path / TRAILER_FILE).exists() and not (tmp_path / HITCH_FILE).exists()


def test_empty_and_bad_files(tmp_path):
    with OutputWriter(tmp_path):
        pass
    assert len(read_tum(tmp_path / TRACTOR_FILE)) == 0
    assert len(read_hitch(tmp_path / HITCH_FILE)) == 0
    (tmp_path / "bad.tum").write_text("0 1 2 3\n")
    with pytest.raises(DatasetError, match="8 columns"):
        read_tum(tmp_path / "bad.tum")
    (tmp_path / "bad.csv").write_text("t,angle\n0,1\n")
    with pytest.raises(DatasetError, match="header"):
        read_hitch(tmp_path / "bad.csv")
    with pytest.raises(DatasetError, match="not found"):
        read_tum(tmp_path / "missing.tum")


def test_write_tum_whole(tmp_path):
    poses = _random_poses(4)
    write_tum(tmp_path / "x.tum", Trajectory(np.arange(4.0), poses))
    np.testing.assert_allclose(read_tum(tmp_path / "x.tum").poses, poses, atol=1e-8)


def test_output_folder_that_cannot_be_created(tmp_path):
    """A file where the output folder should be: OutputError naming it, not a FileExistsError traceback."""
    (tmp_path / "taken").write_text("x")
    for target in (tmp_path / "taken", tmp_path / "taken" / "run"):
        with pytest.raises(OutputError, match="cannot write the outputs there"):
            OutputWriter(target).open()


def test_a_last_line_cut_off_by_a_crash_is_ignored_with_a_warning(tmp_path, caplog):
    """The rows before it are kept (written and flushed one by one); a bad line inside is still an error."""
    poses = _random_poses(5)
    path = tmp_path / TRACTOR_FILE
    write_tum(path, Trajectory(np.arange(5.0), poses))
    text = path.read_text()
    path.write_text(text[:-30])
    with caplog.at_level("WARNING"):
        assert len(read_tum(path)) == 4
    assert "incomplete" in caplog.text
    lines = text.splitlines()
    path.write_text("\n".join(lines[:3] + [lines[3][:-30]] + lines[4:]) + "\n")
    with pytest.raises(DatasetError, match="cannot parse"):
        read_tum(path)


def test_repeated_timestamps_and_non_unit_quaternions_are_errors(tmp_path):
    poses = _random_poses(4)
    path = tmp_path / TRACTOR_FILE
    write_tum(path, Trajectory(np.array([0.0, 1.0, 1.0, 2.0]), poses))
    with pytest.raises(DatasetError, match="not strictly increasing at data row 3"):
        read_tum(path)
    write_tum(path, Trajectory(np.arange(4.0), poses))
    lines = path.read_text().splitlines()
    lines[2] = " ".join(lines[2].split()[:4] + ["0", "0", "0", "0"])  # used to read as the identity rotation
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="data row 2 .*not unit length"):
        read_tum(path)
