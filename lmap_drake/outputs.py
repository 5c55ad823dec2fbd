"""Output folders: complete or absent, marked as ours, locked while written.

A run writes into a hidden temporary sibling of its output folder
(``.NAME.partial-XXXXXX``) and renames it into place when everything is
written. An interrupt or a write error removes the temporary folder, so no
folder that looks complete is left behind; a hard kill leaves only the
hidden ``.partial-`` folder. An existing non-empty output folder is refused
unless ``overwrite`` is set; a folder that another run filled while this one
was writing is never mixed with this run's files (this run's folder gets a
suffix instead).

Ownership (``MARKER``): every folder a command writes holds ``.lmap_drake``
(JSON: the command, its start time, for ``eval`` the options that define
the evaluation), written with the outputs (inside the temporary folder, so
it appears with them). ``overwrite`` replaces only a folder that holds it,
never the input being read (``inputs``: the run being replayed, the
scenario file) nor a folder containing it or inside it. A symlinked output
folder is followed: the folder it points at is replaced, the link stays.

Locks (``FolderLock``): a command holds ``flock`` on ``.NAME.lock`` beside
its output folder for its whole life (the kernel releases it when the
process ends, however it ends): a run with ``overwrite`` and an ``eval``
hold it exclusively, other runs shared, so a second command that could
delete or mix the first's files is refused (``FolderBusy``, exit code 2)
naming the folder. The lock file is removed by its last holder; a killed
command leaves it unlocked, and the next command reuses it.
"""
from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import secrets
import shutil
from pathlib import Path

from lmap_drake.errors import OutputError

MARKER = ".lmap_drake"          # in every output folder: says the folder is ours
LOCK_SUFFIX = ".lock"            # ``.NAME.lock`` beside the output folder NAME
MARKER_FORMAT = 1


class FolderBusy(OutputError):
    """Another lmap-drake command holds the output folder's lock."""


class NotOurs(OutputError):
    """``--overwrite`` (or an in-place writer) met a folder lmap-drake did not
    write, or the input being read."""


def DefaultOutputFolder(root: str | Path = "out", prefix: str = "") -> Path:
    """``root/<prefix><YYYYmmdd-HHMMSS>-<6 hex>``: unique even for runs
    started in the same second."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path(root) / f"{prefix}{stamp}-{secrets.token_hex(3)}"


def _Describe(err: OSError) -> str:
    return err.strerror or str(err)


# ------------------------------------------------------------------ marker
def ReadMarker(folder: str | Path) -> dict | None:
    """The marker of ``folder`` (``{"command": ...}``), None when it has none
    (a marker that is not a JSON map counts as none)."""
    path = Path(folder) / MARKER
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("command"), str) else None


def WriteMarker(folder: str | Path, command: str, **extra) -> None:
    """Writes ``folder/.lmap_drake`` atomically (a temporary file renamed)."""
    folder = Path(folder)
    data = dict(lmap_drake=MARKER_FORMAT, command=command,
                created=_dt.datetime.now().astimezone().isoformat(timespec="seconds"),
                pid=os.getpid(), **extra)
    tmp = folder / f"{MARKER}.{secrets.token_hex(3)}.tmp"
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, folder / MARKER)


def _NonEmpty(folder: Path) -> bool:
    return folder.is_dir() and any(folder.iterdir())


def CheckNotInput(output: str | Path, inputs=()) -> None:
    """NotOurs when ``output`` is, contains or is inside one of ``inputs``
    (paths being read: a run folder being replayed, a scenario file)."""
    out = Path(output).resolve()
    for given in inputs:
        if given is None:
            continue
        inp = Path(given).resolve()
        if out == inp or out in inp.parents or inp in out.parents:
            what = ("is" if out == inp else "contains" if out in inp.parents else "is inside")
            raise NotOurs(f"output folder {output} {what} the input {given}: choose an "
                          f"--output outside it")


def CheckOverwritable(folder: str | Path) -> None:
    """NotOurs unless ``folder`` is absent, empty or an lmap-drake output (its
    marker): ``--overwrite`` deletes nothing else."""
    folder = Path(folder)
    if _NonEmpty(folder) and ReadMarker(folder) is None:
        raise NotOurs(f"output folder {folder} is not an lmap-drake output (it has no "
                      f"{MARKER} marker): --overwrite replaces only folders lmap-drake "
                      f"wrote; move it away yourself or choose another --output")


# -------------------------------------------------------------------- lock
def LockPath(folder: str | Path) -> Path:
    """``.NAME.lock`` beside the (symlink-resolved) folder NAME."""
    real = Path(os.path.abspath(Path(folder).resolve()))
    if not real.name:
        raise OutputError(f"output folder {folder} cannot be the file system root")
    return real.parent / f".{real.name}{LOCK_SUFFIX}"


class FolderLock:
    """``flock`` on ``LockPath(folder)``, exclusive or ``shared``, taken now
    (never waiting: FolderBusy naming the folder when another command holds
    it) and held until ``Release()`` or the process ends. Creates the
    folder's parents."""

    def __init__(self, folder: str | Path, shared: bool = False):
        self.fd: int | None = None
        self.folder = Path(folder)
        self.path = LockPath(folder)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OutputError(f"cannot create the output folder's parent "
                              f"{self.path.parent}: {_Describe(err)}") from None
        mode = fcntl.LOCK_SH if shared else fcntl.LOCK_EX
        for _ in range(20):
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as err:
                raise OutputError(f"cannot write the output folder {folder} (lock file "
                                  f"{self.path}): {_Describe(err)}") from None
            try:
                fcntl.flock(fd, mode | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _ReadHolder(fd)
                os.close(fd)
                raise FolderBusy(f"output folder {folder} is in use by another lmap-drake "
                                 f"command ({holder}lock {self.path}): wait for it or "
                                 f"choose another --output") from None
            try:          # the previous holder may have removed the file meanwhile
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                self.fd = fd
                if not shared:
                    os.ftruncate(fd, 0)
                    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
                return
            os.close(fd)
        raise FolderBusy(f"output folder {folder}: its lock {self.path} keeps changing")

    def Release(self) -> None:
        """Unlocks; the last holder removes the lock file."""
        fd, self.fd = self.fd, None
        if fd is None:
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)     # nobody else holds it
            try:
                os.unlink(self.path)
            except OSError:
                pass
        except OSError:
            pass
        os.close(fd)

    def __enter__(self) -> "FolderLock":
        return self

    def __exit__(self, *exc) -> None:
        self.Release()

    def __del__(self):
        self.Release()


def _ReadHolder(fd: int) -> str:
    try:
        pid = os.pread(fd, 32, 0).decode().strip()
    except (OSError, UnicodeDecodeError):
        return ""
    return f"pid {pid}, " if pid.isdigit() else ""


# --------------------------------------------------------- in-place folders
def EnsureWritableFolder(folder: str | Path) -> Path:
    """Creates ``folder`` (and parents) for in-place writing; OutputError
    naming the path when it is a file or not writable."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"output path {folder} exists and is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{secrets.token_hex(3)}"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        raise OutputError(f"cannot write to output folder {folder}: {_Describe(err)}") from None
    return folder


def _Option(key: str) -> str:
    return f"--{key}"


class InPlaceFolder:
    """An output folder written in place over a command's life (``eval``),
    claimed before anything is written: the lock (exclusive), then the
    folder must be absent or empty, or, with ``resume``, an output of the
    same ``command`` whose ``options`` (the marker's record of the command's
    identity, e.g. ``--seed``) equal these; the first differing option is
    named; with ``overwrite`` (``twin``; None: the command has no such
    option), a non-empty folder must be an lmap-drake output, emptied by
    ``Start()``. ``inputs``: paths being read,
    which the folder may not be, contain or be inside. Nothing is written
    until ``Start()`` (creates the folder, writes
    the marker; a folder of a version without markers gets it when the
    command ends well). Leaving the ``with`` block on an exception removes the
    folder when this command created it and ``kept(folder)`` says nothing
    worth keeping is inside."""

    def __init__(self, folder: str | Path, command: str, options: dict,
                 resume: bool = False, legacy=(), kept=None, overwrite: bool | None = None,
                 inputs=()):
        self.path = Path(folder)
        self.command, self.options = command, dict(options)
        self.kept = kept or (lambda p: False)
        self.created = self.clear = False
        p = self.path
        if p.exists() and not p.is_dir():
            raise OutputError(f"output path {p} exists and is not a folder")
        CheckNotInput(p, inputs)
        self.lock = FolderLock(p)
        try:
            if overwrite and not resume and _NonEmpty(p):
                CheckOverwritable(p)        # ours: emptied by Start(), not before
                self.clear, self.marker = True, None
                return
            self.marker = self._Check(resume, legacy, overwrite is not None)
        except BaseException:
            self.lock.Release()
            raise

    def _Check(self, resume: bool, legacy, has_overwrite: bool = False) -> dict | None:
        p = self.path
        if not _NonEmpty(p):
            return None
        marker = ReadMarker(p)
        ours = marker is not None or any((p / name).exists() for name in legacy)
        if not resume:
            again = "--overwrite to replace it" if has_overwrite else "--resume to continue it"
            raise NotOurs(f"output folder {p} exists and is not empty: "
                          + (f"pass {again}, or choose another --output"
                             if ours else "choose another --output"))
        if not ours:
            raise NotOurs(f"output folder {p} is not an lmap-drake {self.command} output "
                          f"(no {MARKER} marker): --resume continues only those; choose "
                          f"another --output")
        if marker is not None and marker["command"] != self.command:
            raise NotOurs(f"output folder {p} holds the output of lmap-drake "
                          f"{marker['command']}, not of {self.command}: choose another "
                          f"--output")
        old = (marker or {}).get("options")
        if isinstance(old, dict):
            for key, value in self.options.items():
                if key in old and old[key] != value:
                    raise NotOurs(
                        f"--resume with {_Option(key)} {_Show(value)}, but {p} was started "
                        f"with {_Option(key)} {_Show(old[key])}: continue it with the same "
                        f"options, or choose another --output for these")
        return marker

    def Start(self) -> Path:
        """Creates the folder (and parents) and writes the marker (kept as
        it is when it already records the options)."""
        if not self.path.exists():
            self.created = True
        if self.clear:
            CheckOverwritable(self.path)        # still ours
            for child in self.path.iterdir():
                if child.is_dir() and not child.is_symlink():
                    shutil.rmtree(child)
                else:
                    child.unlink()
        legacy = _NonEmpty(self.path) and self.marker is None
        EnsureWritableFolder(self.path)
        if not legacy and not isinstance((self.marker or {}).get("options"), dict):
            self._Mark()
        return self.path

    def _Mark(self) -> None:
        WriteMarker(self.path, self.command, options=self.options)
        self.marker = ReadMarker(self.path)

    def __enter__(self) -> "InPlaceFolder":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is not None and self.created and not self.kept(self.path):
                shutil.rmtree(self.path, ignore_errors=True)
            elif exc_type is None and self.path.is_dir() and self.marker is None:
                self._Mark()        # a folder of a version without markers, continued
        finally:
            self.lock.Release()
        return False


def _Show(value) -> str:
    if isinstance(value, list):
        return ",".join(str(v) for v in value) or "''"
    if isinstance(value, str):
        return value if value and " " not in value else repr(value)
    return str(value)


# ----------------------------------------------------------- whole folders
class OutputFolder:
    """``with OutputFolder(final, overwrite) as tmp:`` write into ``tmp``;
    on a clean exit it becomes ``final`` (``self.final``, which may carry a
    suffix if another run took ``final`` meanwhile); on an exception it is
    removed. ``command``: written to the marker (none without it).
    ``inputs``: paths being read, which the output may not be, contain or
    be inside. The lock is taken here and released on exit."""

    def __init__(self, final: str | Path, overwrite: bool = False,
                 command: str | None = None, inputs=()):
        self.requested = Path(final)
        self.final = self.requested
        self.overwrite = overwrite
        self.command = command
        final = self.requested
        if final.exists() or final.is_symlink():
            if not final.is_dir():
                raise OutputError(f"output path {final} exists and is not a folder")
            if any(final.iterdir()) and not overwrite:
                raise OutputError(f"output folder {final} exists and is not empty: pass "
                                  f"--overwrite to replace it, or choose another --output")
        CheckNotInput(final, inputs)
        # A symlink is followed: its target is replaced, the link stays.
        self.real = Path(os.path.abspath(final.resolve())) if final.is_symlink() else final
        self.lock = FolderLock(final, shared=not overwrite)
        try:
            if overwrite:
                CheckOverwritable(final)
            parent = self.real.parent
            try:
                parent.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise OutputError(f"cannot create the output folder's parent {parent}: "
                                  f"{_Describe(err)}") from None
            self.tmp = parent / f".{self.real.name}.partial-{secrets.token_hex(3)}"
            try:
                self.tmp.mkdir()
            except OSError as err:
                raise OutputError(f"cannot write the output folder {final} (in {parent}): "
                                  f"{_Describe(err)}") from None
        except BaseException:
            self.lock.Release()
            raise

    def __enter__(self) -> Path:
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is not None:
                shutil.rmtree(self.tmp, ignore_errors=True)
                return False
            try:
                if self.command:
                    WriteMarker(self.tmp, self.command)
                self._Commit()
            except BaseException:
                shutil.rmtree(self.tmp, ignore_errors=True)
                raise
            return False
        finally:
            self.lock.Release()

    def _Commit(self) -> None:
        final = self.real
        if self.overwrite and final.is_dir() and any(final.iterdir()):
            CheckOverwritable(final)          # still ours (it may have changed meanwhile)
            old = final.parent / f".{final.name}.old-{secrets.token_hex(3)}"
            os.rename(final, old)
            try:
                os.rename(self.tmp, final)
            except OSError:
                os.rename(old, final)
                raise
            shutil.rmtree(old, ignore_errors=True)
            return
        try:
            os.rename(self.tmp, final)   # atomic; replaces an empty folder only
        except OSError:
            if not final.exists():
                raise
            # Another run filled ``final`` while this one was writing: keep
            # both complete, never mixed.
            self.final = final.parent / f"{final.name}-{secrets.token_hex(3)}"
            os.rename(self.tmp, self.final)
