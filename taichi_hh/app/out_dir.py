"""A command's output directory: refused before any work when it cannot be
written, and left without the files of a command that failed."""
from __future__ import annotations

import os


def prepare_out_dir(out: str) -> None:
    """Refuse an --out that is a file or cannot be created or written, before
    any work; remove temporary files a killed earlier run left there."""
    from ..errors import InputError
    from .io import remove_stale_temp_files
    if os.path.exists(out) and not os.path.isdir(out):
        raise InputError(f"--out {out}: is a file, not a directory")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {out}: cannot create the directory "
                         f"({exc.strerror or exc})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"--out {out}: the directory is not writable")
    remove_stale_temp_files(out)


class WrittenOnSuccess:
    """Files in ``out`` written (or rewritten) inside the block are removed if
    the block raises: a command that exits with an error leaves no result
    files of its own behind (e.g. components.npz when a figure fails)."""

    def __init__(self, out: str):
        self.out = out

    def _files(self) -> dict:
        try:
            return {e.name: e.stat().st_mtime_ns for e in os.scandir(self.out) if e.is_file()}
        except OSError:
            return {}

    def __enter__(self):
        self.before = self._files()
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            for name, mtime in self._files().items():
                if self.before.get(name) != mtime:
                    try:
                        os.remove(os.path.join(self.out, name))
                    except OSError:
                        pass
        return False
