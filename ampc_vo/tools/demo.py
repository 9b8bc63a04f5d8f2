"""The built-in demo sequence: the demo route rendered once into a cache folder (issue 7).

``scripts/run_odometry.py`` without a dataset runs on :func:`demo_dataset`: the first call
simulates ``configs/sim/demo.yaml`` with images (about a minute on two cores) into
``$AMPC_VO_CACHE`` (default ``~/.cache/ampc_vo``), later calls reuse it. The folder name carries
a hash of the route and rig files, so editing them renders anew; an interrupted render (Ctrl-C,
SIGTERM) removes its folder, and one left half-written otherwise (SIGKILL) has no completion
marker and is rendered again.
"""
from __future__ import annotations

import hashlib
import logging
import os
import shutil
from pathlib import Path

from ampc_vo.errors import ConfigError

logger = logging.getLogger(__name__)

CACHE_ENVIRONMENT = "AMPC_VO_CACHE"
COMPLETE_MARKER = ".complete"
DEMO_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "sim" / "demo.yaml"
# bump when the scene or the renderer change what a rendered sequence looks like (stale caches re-render)
SCENE_VERSION = "2"


def cache_root() -> Path:
    """``$AMPC_VO_CACHE`` or ``~/.cache/ampc_vo``."""
    configured = os.environ.get(CACHE_ENVIRONMENT)
    return Path(configured).expanduser() if configured else Path.home() / ".cache" / "ampc_vo"


def _fingerprint(config_path: Path) -> str:
    """Hash of the scene version, the simulation config and its rig file (what the rendered sequence depends on)."""
    from ampc_vo.sim.config import load_sim_config

    config = load_sim_config(config_path)
    digest = hashlib.sha256(SCENE_VERSION.encode())
    digest.update(config_path.read_bytes())
    digest.update(Path(config.rig_path).read_bytes())
    return digest.hexdigest()[:12]


def demo_dataset(config_path: str | Path = DEMO_CONFIG, cache: str | Path | None = None, progress: bool = True) -> Path:
    """The demo dataset folder (with images), simulated and rendered on first use."""
    config_path = Path(config_path)
    if not config_path.is_file():
        raise ConfigError(f"{config_path}: demo route config not found (run from a source checkout: pip install -e .)")
    root = Path(cache) if cache is not None else cache_root()
    folder = root / f"{config_path.stem}-{_fingerprint(config_path)}"
    if (folder / COMPLETE_MARKER).is_file():
        logger.info("demo sequence from the cache: %s", folder)
        return folder
    if folder.exists():
        logger.warning("%s: incomplete demo sequence (interrupted render?): rendering it again", folder)
        shutil.rmtree(folder)
    from ampc_vo.sim.simulation import simulate_dataset

    logger.warning("rendering the demo sequence into %s (first run only, about a minute)", folder)
    try:
        result = simulate_dataset(config_path, folder, with_images=True, progress=progress)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (ampc_vo.tools.cli): no half-rendered folder is left
        logger.warning("demo render interrupted: %s removed (it is rendered again next time)", folder)
        shutil.rmtree(folder, ignore_errors=True)
        raise
    if not result.images_written:
        raise ConfigError("the renderer is not available: the demo needs rendered images")
    (folder / COMPLETE_MARKER).write_text("complete\n", encoding="utf-8")
    return folder
