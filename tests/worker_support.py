"""Module-level streams for tests/test_worker.py (a spawned worker process imports them by name)."""
from __future__ import annotations

import logging
import os
from typing import Iterator

from ampc_vo.errors import DatasetError


def count_up(stop: int) -> Iterator[int]:
    yield from range(stop)


def fail_after(count: int) -> Iterator[int]:
    yield from range(count)
    raise DatasetError("image 000007.png cannot be decoded")


def log_then_stop(message: str) -> Iterator[int]:
    logging.getLogger("ampc_vo.frontend.tracker").warning(message)
    logging.getLogger("ampc_vo.frontend.tracker").debug("not shown at INFO")
    yield 1


def die_after(count: int) -> Iterator[int]:
    yield from range(count)
    os._exit(3)


def forever() -> Iterator[int]:
    value = 0
    while True:
        yield value
        value += 1
