"""The built-in demo sequence cache (ampc_vo.tools.demo): rendered once, reused, rendered again when the
route changes or a render was interrupted; the cache folder follows $AMPC_VO_CACHE."""
from __future__ import annotations

from pathlib import Path

import pytest

import ampc_vo.sim.simulation
from ampc_vo.tools import demo
from ampc_vo.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]

TINY_ROUTE = """\
rig: {rig}
rate_hz: 10
speed: 8.0
seed: 3
max_tracks_per_camera: 50
segments:
  - {{type: straight, length: 4}}
scene: {{extension_m: 20}}
"""


@pytest.fixture
def tiny_route(tmp_path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY_ROUTE.format(rig=ROOT / "configs" / "rigs" / "default.yaml"))
    return path


def _no_rendering(*args, **kwargs):
    raise AssertionError("rendered again")


def test_rendered_once_then_reused(tiny_route, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    folder = demo.demo_dataset(tiny_route, cache=cache, progress=False)
    assert folder.parent == cache and folder.name.startswith("tiny-")
    assert (folder / demo.COMPLETE_MARKER).is_file() and (folder / "frames.csv").is_file()
    assert len(list((folder / "images" / "front").glob("*.png"))) >= 5
    monkeypatch.setattr(ampc_vo.sim.simulation, "simulate_dataset", _no_rendering)
    assert demo.demo_dataset(tiny_route, cache=cache, progress=False) == folder


def test_an_interrupted_render_is_done_again(tiny_route, tmp_path):
    cache = tmp_path / "cache"
    folder = demo.demo_dataset(tiny_route, cache=cache, progress=False)
    (folder / demo.COMPLETE_MARKER).unlink()
    (folder / "images" / "front" / "000000.png").write_bytes(b"half written")
    assert demo.demo_dataset(tiny_route, cache=cache, progress=False) == folder
    assert (folder / demo.COMPLETE_MARKER).is_file()
    assert (folder / "images" / "front" / "000000.png").read_bytes()[:4] == b"\x89PNG"


def test_a_changed_route_gets_its_own_folder(tiny_route, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    first = demo.demo_dataset(tiny_route, cache=cache, progress=False)
    tiny_route.write_text(tiny_route.read_text().replace("seed: 3", "seed: 4"))
    rendered = []

    def record(config, folder, **kwargs):
        Path(folder).mkdir(parents=True)
        rendered.append(Path(folder))
        return _Result()

    monkeypatch.setattr(ampc_vo.sim.simulation, "simulate_dataset", record)
    second = demo.demo_dataset(tiny_route, cache=cache, progress=False)
    assert second != first and rendered == [second]
    assert (first / demo.COMPLETE_MARKER).is_file()  # the other route's folder stays


class _Result:
    images_written = True


def test_cache_folder_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(demo.CACHE_ENVIRONMENT, str(tmp_path / "elsewhere"))
    assert demo.cache_root() == tmp_path / "elsewhere"
    monkeypatch.delenv(demo.CACHE_ENVIRONMENT)
    assert demo.cache_root() == Path.home() / ".cache" / "ampc_vo"


def test_missing_route_config_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="demo route config not found"):
        demo.demo_dataset(tmp_path / "missing.yaml", cache=tmp_path)
