"""Output folders that are complete or absent.

A run writes into a hidden temporary sibling of its output folder
(``.NAME.partial-XXXXXX``) and renames it into place when everything is
written. An interrupt or a write error removes the temporary folder, so no
folder that looks complete is left behind; a hard kill leaves only the
hidden ``.partial-`` folder. An existing non-empty output folder is refused
unless ``overwrite`` is set; a folder that another run filled while this one
was writing is never mixed with this run's files (this run's folder gets a
suffix instead).
"""
from __future__ import annotations

import datetime as _dt
import os
import secrets
import shutil
from pathlib import Path

from lmap_drake.errors import OutputError


def DefaultOutputFolder(root: str | Path = "out", prefix: str = "") -> Path:
    """``root/<prefix><YYYYmmdd-HHMMSS>-<6 hex>``: unique even for runs
    started in the same second."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path(root) / f"{prefix}{stamp}-{secrets.token_hex(3)}"


def _Describe(err: OSError) -> str:
    return err.strerror or str(err)


def EnsureWritableFolder(folder: str | Path) -> Path:
    """Creates ``folder`` (and parents) for in-place writing (``eval``);
    OutputError naming the path when it is a file or not writable."""
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


class OutputFolder:
    """``with OutputFolder(final, overwrite) as tmp:`` write into ``tmp``;
    on a clean exit it becomes ``final`` (``self.final``, which may carry a
    suffix if another run took ``final`` meanwhile); on an exception it is
    removed."""

    def __init__(self, final: str | Path, overwrite: bool = False):
        self.requested = Path(final)
        self.final = self.requested
        self.overwrite = overwrite
        final = self.requested
        if final.exists() or final.is_symlink():
            if not final.is_dir():
                raise OutputError(f"output path {final} exists and is not a folder")
            if any(final.iterdir()) and not overwrite:
                raise OutputError(f"output folder {final} exists and is not empty: pass "
                                  f"--overwrite to replace it, or choose another --output")
        parent = final.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OutputError(f"cannot create the output folder's parent {parent}: "
                              f"{_Describe(err)}") from None
        self.tmp = parent / f".{final.name}.partial-{secrets.token_hex(3)}"
        try:
            self.tmp.mkdir()
        except OSError as err:
            raise OutputError(f"cannot write the output folder {final} (in {parent}): "
                              f"{_Describe(err)}") from None

    def __enter__(self) -> Path:
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return False
        try:
            self._Commit()
        except BaseException:
            shutil.rmtree(self.tmp, ignore_errors=True)
            raise
        return False

    def _Commit(self) -> None:
        final = self.requested
        if self.overwrite and final.is_dir() and any(final.iterdir()):
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
