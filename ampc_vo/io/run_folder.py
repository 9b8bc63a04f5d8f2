"""One run per output folder, and every file in it traceable to that run (issue 14, DESIGN section 5).

An output folder (``--out``) holds the files of exactly one run:

* ``run.lock`` exists while a run (or an evaluation) writes there; it holds the writer's PID, host
  and process start time. A second run into the same folder is refused while that process lives
  (:class:`~ampc_vo.errors.OutputError`); a lock left by a killed process (the PID is gone or is
  another process now) is taken over with a warning.
* ``run.json`` is the run's manifest: ``run_id`` (random), command, PID, dataset, start and end
  time, ``state`` (``running`` until the end, then ``done``, ``failed`` or ``interrupted``; a run
  killed by SIGKILL stays ``running`` with a dead lock) and ``files``: every file the run wrote.
* every output file carries the run id: a ``# ampc-vo run <id>`` comment line in text files
  (``tractor.tum``, ``trailer.tum``, ``hitch.csv``, ``config.yaml``), a ``run_id`` entry in JSON files.

When a run starts, the files an earlier run left (those its ``run.json`` lists, plus the known
output names for folders written before run.json existed) are removed, so nothing stale is mixed
in: a tractor-only run leaves no old ``trailer.tum``, a killed run no old ``timing.json``.
Readers (:func:`check_run_files`) refuse a file that another run wrote.
"""
from __future__ import annotations

import json
import logging
import os
import socket
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from ampc_vo.errors import OutputError, WriteError

logger = logging.getLogger(__name__)

RUN_FILE = "run.json"
LOCK_FILE = "run.lock"
RUN_TAG = "# ampc-vo run "  # the provenance comment line of text outputs: RUN_TAG + run id
TIMING_FILE = "timing.json"
CONFIG_FILE = "config.yaml"
METRICS_FILE = "metrics.json"
PLOT_FILE = "evaluation.png"
# every file name a run or its evaluation writes (DESIGN section 5); removed when a new run starts
OUTPUT_FILES = ("tractor.tum", "trailer.tum", "hitch.csv", TIMING_FILE, CONFIG_FILE, METRICS_FILE, PLOT_FILE)
STATE_RUNNING, STATE_DONE, STATE_FAILED, STATE_INTERRUPTED = "running", "done", "failed", "interrupted"


# ---------------------------------------------------------------------- process liveness
def _process_start_ticks(pid: int) -> int | None:
    """Start time of process ``pid`` in clock ticks since boot (Linux ``/proc/PID/stat`` field 22),
    ``None`` where unknown: with it a reused PID is not mistaken for the lock's owner."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
        return int(text.rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def process_alive(pid: int, start_ticks: int | None = None) -> bool:
    """True if process ``pid`` exists (and, when ``start_ticks`` is known, is the same process)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        pass
    if start_ticks is None:
        return True
    current = _process_start_ticks(pid)
    return current is None or current == start_ticks


@dataclass(frozen=True)
class LockOwner:
    """Who holds ``run.lock``: PID, host, process start time, run id."""

    pid: int
    host: str
    start_ticks: int | None
    run_id: str

    @property
    def alive(self) -> bool:
        """Alive, as far as this host can tell (a lock of another host counts as alive)."""
        return self.host != socket.gethostname() or process_alive(self.pid, self.start_ticks)


def read_lock(directory: str | Path) -> LockOwner | None:
    """The owner recorded in ``directory/run.lock``, or ``None`` without a (readable) lock."""
    try:
        raw = json.loads((Path(directory) / LOCK_FILE).read_text(encoding="utf-8"))
        return LockOwner(int(raw["pid"]), str(raw["host"]), raw.get("start_ticks"), str(raw.get("run_id", "")))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError):
        return LockOwner(0, socket.gethostname(), None, "")  # unreadable (cut off while written): dead


def _create_exclusively(path: Path, content: str) -> bool:
    """Create ``path`` holding ``content`` unless it exists (False then). The content is written to
    a private file first and hard-linked into place (atomic: a reader never sees an empty lock);
    where hard links are not supported, ``O_EXCL`` creation."""
    private = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}")
    try:
        private.write_text(content, encoding="utf-8")
        try:
            os.link(private, path)
            return True
        except FileExistsError:
            return False
        except OSError:  # no hard links here (some network or FUSE file systems)
            try:
                descriptor = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                return False
            with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
                handle.write(content)
            return True
    finally:
        private.unlink(missing_ok=True)


def _acquire_lock(directory: Path, run_id: str) -> None:
    """Create ``run.lock`` exclusively (of two runs started at once only one succeeds); a lock whose
    owner is dead is taken over with a warning."""
    content = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "start_ticks": _process_start_ticks(os.getpid()), "run_id": run_id}) + "\n"
    for _ in range(3):
        try:
            if _create_exclusively(directory / LOCK_FILE, content):
                return
        except OSError as error:
            raise OutputError(f"{directory}: cannot write there ({error.strerror or error})") from None
        owner = read_lock(directory)
        if owner is not None and owner.alive:
            raise OutputError(f"{directory}: in use by another run (PID {owner.pid} on {owner.host}, {directory / LOCK_FILE}); "
                              "wait for it to end or choose another --out")
        logger.warning("%s: taking over the lock of a run that no longer exists (PID %s, killed?)", directory, owner.pid if owner else "?")
        (directory / LOCK_FILE).unlink(missing_ok=True)
    raise OutputError(f"{directory}: cannot take {LOCK_FILE} (another run keeps taking it)")


# ---------------------------------------------------------------------- manifest
@dataclass
class RunRecord:
    """The content of ``run.json`` (module docstring)."""

    run_id: str
    command: str
    pid: int
    host: str
    started: str
    state: str = STATE_RUNNING
    ended: str | None = None
    dataset: str | None = None
    message: str | None = None
    files: list[str] = field(default_factory=list)

    def to_json(self) -> str:
        return json.dumps(self.__dict__, indent=2) + "\n"


def read_run(directory: str | Path) -> RunRecord | None:
    """``directory/run.json``, or ``None`` when absent; :class:`OutputError` when unreadable."""
    path = Path(directory) / RUN_FILE
    if not path.is_file():
        return None
    required = ("run_id", "command", "pid", "host", "started")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(raw, dict) or any(key not in raw for key in required) or not isinstance(raw.get("files", []), list):
            raise ValueError(f"expected a mapping with {', '.join(required)} and a list of files")
        return RunRecord(**{key: raw[key] for key in RunRecord.__dataclass_fields__ if key in raw})
    except (OSError, ValueError, TypeError, UnicodeDecodeError) as error:
        raise OutputError(f"{path}: unreadable run manifest ({error}); run the odometry into this folder again") from None


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def _write_atomically(path: Path, text: str) -> None:
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)


def embedded_run_id(path: str | Path) -> str | None:
    """The run id a file carries (``run_id`` of a JSON file, else a ``# ampc-vo run`` line among the
    first three), ``None`` when it carries none."""
    path = Path(path)
    try:
        if path.suffix == ".json":
            value = json.loads(path.read_text(encoding="utf-8")).get("run_id")
            return None if value is None else str(value)
        with open(path, encoding="utf-8", errors="replace") as handle:
            for _ in range(3):
                line = handle.readline()
                if line.startswith(RUN_TAG):
                    return line[len(RUN_TAG):].strip()
    except (OSError, ValueError, AttributeError):
        return None
    return None


class RunFolder:
    """Context manager owning an output folder for one run (module docstring).

    On entry: creates the folder, takes ``run.lock`` (or :class:`OutputError`), removes the files of
    an earlier run and writes ``run.json`` (state ``running``). :meth:`path` names a file this run
    writes (and records it); on exit the state becomes ``done``, ``interrupted`` (Ctrl-C, SIGTERM)
    or ``failed`` and the lock is released.
    """

    def __init__(self, directory: str | Path, command: str = "run_odometry", dataset: str | Path | None = None) -> None:
        self.directory = Path(directory)
        self.record = RunRecord(run_id=uuid.uuid4().hex[:16], command=command, pid=os.getpid(), host=socket.gethostname(), started=_now(),
                                dataset=None if dataset is None else str(Path(dataset).resolve()))
        self._locked = False

    @property
    def run_id(self) -> str:
        return self.record.run_id

    @property
    def tag(self) -> str:
        """The provenance comment line of this run's text outputs."""
        return RUN_TAG + self.run_id

    def __enter__(self) -> "RunFolder":
        if self.directory.exists() and not self.directory.is_dir():
            raise OutputError(f"{self.directory}: is a file, not a folder (--out names the output folder)")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise OutputError(f"{self.directory}: cannot create the output folder ({error.strerror or error})") from None
        if not self.directory.is_dir():
            raise OutputError(f"{self.directory}: not a folder")
        _acquire_lock(self.directory, self.run_id)
        self._locked = True
        try:
            self._remove_earlier_outputs()
            self._save()
        except BaseException:
            self._release()
            raise
        return self

    def _remove_earlier_outputs(self) -> None:
        try:
            earlier = read_run(self.directory)
        except OutputError as error:
            logger.warning("%s", error)
            earlier = None
        names = set(OUTPUT_FILES) | set(earlier.files if earlier else [])
        removed = []
        for name in sorted(names):
            path = self.directory / name
            if Path(name).name != name or not (path.is_file() or path.is_symlink()):
                continue
            try:
                path.unlink()
            except OSError as error:
                raise OutputError(f"{path}: cannot remove this file of an earlier run ({error.strerror or error}); remove it or choose another --out") from None
            removed.append(name)
        if removed:
            logger.info("%s: removed %s of an earlier run%s", self.directory, ", ".join(removed), f" ({earlier.run_id})" if earlier else "")

    def path(self, name: str) -> Path:
        """The path of output file ``name``, recorded in ``run.json`` as written by this run."""
        if name not in self.record.files:
            self.record.files.append(name)
            self._save()
        return self.directory / name

    def write_text(self, name: str, text: str) -> Path:
        """Write a whole output file; :class:`WriteError` (the run's other files stay) on failure."""
        path = self.path(name)
        try:
            _write_atomically(path, text)
        except OSError as error:
            raise WriteError(f"{path}: cannot write ({error.strerror or error}); the files written before are kept") from None
        return path

    def _save(self) -> None:
        try:
            _write_atomically(self.directory / RUN_FILE, self.record.to_json())
        except OSError as error:
            raise WriteError(f"{self.directory / RUN_FILE}: cannot write ({error.strerror or error})") from None

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None) -> None:
        if kind is None:
            self.record.state = STATE_DONE
        elif issubclass(kind, KeyboardInterrupt):
            self.record.state = STATE_INTERRUPTED
        else:
            self.record.state, self.record.message = STATE_FAILED, f"{kind.__name__}: {error}"
        self.record.ended = _now()
        try:
            self._save()
        except WriteError as problem:  # the run's own error (if any) is the one to report
            logger.error("%s", problem)
            if kind is None:
                raise
        finally:
            self._release()

    def _release(self) -> None:
        if self._locked:
            self._locked = False
            try:
                (self.directory / LOCK_FILE).unlink()
            except OSError:
                pass


# ---------------------------------------------------------------------- readers
@dataclass(frozen=True)
class RunFiles:
    """What a reader of an output folder may use: the run's record (``None``: the folder has no
    run.json, e.g. trajectories of another tool) and which of the asked-for files belong to it."""

    record: RunRecord | None
    present: dict[str, Path]
    killed: bool = False


def check_run_files(directory: str | Path, names: tuple[str, ...]) -> RunFiles:
    """The files ``names`` of the run in ``directory`` that exist, after checking their provenance:
    :class:`OutputError` while a run still writes there, or for a file another run wrote (not in
    ``run.json``, or carrying another run id). A run that was killed (state ``running``, lock dead)
    is reported with ``killed`` (its poses so far are usable) and a warning."""
    directory = Path(directory)
    owner = read_lock(directory)
    if owner is not None and owner.alive:
        raise OutputError(f"{directory}: a run is still writing there (PID {owner.pid}, {directory / LOCK_FILE}); evaluate it when it has ended")
    record = read_run(directory)
    present = {name: directory / name for name in names if (directory / name).is_file()}
    if record is None:
        if present:
            logger.warning("%s: no %s: cannot tell which run wrote %s", directory, RUN_FILE, ", ".join(present))
        return RunFiles(None, present)
    for name, path in present.items():
        carried = embedded_run_id(path)
        if name not in record.files or (carried is not None and carried != record.run_id):
            raise OutputError(f"{path}: not written by the run recorded in {directory / RUN_FILE} ({record.run_id}): a stale file of another run; "
                              "remove it or run into an empty folder")
    killed = record.state == STATE_RUNNING
    if killed:
        logger.warning("%s: run %s did not end (killed?): using the estimates it wrote", directory, record.run_id)
    elif record.state != STATE_DONE:
        logger.warning("%s: run %s %s%s: using the estimates it wrote", directory, record.run_id, record.state,
                       f" ({record.message})" if record.message else "")
    return RunFiles(record, present, killed)


class FolderClaim:
    """Hold ``run.lock`` of an existing run folder while adding files to it (the evaluation's
    ``metrics.json``, ``evaluation.png``), recording them in its ``run.json`` when there is one."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.record = read_run(self.directory)
        self._token = uuid.uuid4().hex[:16]

    def __enter__(self) -> "FolderClaim":
        _acquire_lock(self.directory, self._token)
        return self

    def path(self, name: str) -> Path:
        if self.record is not None and name not in self.record.files:
            self.record.files.append(name)
            try:
                _write_atomically(self.directory / RUN_FILE, self.record.to_json())
            except OSError as error:
                raise WriteError(f"{self.directory / RUN_FILE}: cannot write ({error.strerror or error})") from None
        return self.directory / name

    @property
    def run_id(self) -> str | None:
        return None if self.record is None else self.record.run_id

    def __exit__(self, *_: object) -> None:
        try:
            (self.directory / LOCK_FILE).unlink()
        except OSError:
            pass
