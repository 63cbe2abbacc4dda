"""Shared pieces of the command-line tools (train.py, eval.py, `python -m match_jax.experiments`): an
argument parser whose errors end with the one line that matters, and a check that an output path can
be written, made before any work."""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors print a one-line usage (`short_usage`, pointing to --help) and
    then the error line, instead of the usage of every option."""

    def __init__(self, *args, short_usage: str = "[options]", **kwargs):
        super().__init__(*args, **kwargs)
        self.short_usage = short_usage

    def error(self, message: str):
        sys.stderr.write(f"usage: {self.prog} {self.short_usage} (see --help)\n")
        self.exit(2, f"{self.prog}: error: {message}\n")


def unwritable(path: str | pathlib.Path, directory: bool = False) -> str | None:
    """Why `path` (a file; with directory=True a directory) cannot be written, or None if it can: a
    directory in a file's place, a file in a folder's place on the way, or a folder that takes no new
    files (probed by creating and removing a temporary file in the deepest folder that exists)."""
    path = pathlib.Path(path)
    place = path
    try:
        if path.exists():
            if directory and not path.is_dir():
                return f"{path} is a file, not a directory"
            if not directory and path.is_dir():
                return f"{path} is a directory"
            if not directory and not os.access(path, os.W_OK):
                return f"{path} is not writable"
        place = path if directory else path.parent
        while not place.exists() and place != place.parent:
            place = place.parent
        if not place.is_dir():
            return f"{place} is a file, not a directory"
        tempfile.NamedTemporaryFile(dir=place, prefix=".write_check_").close()
    except OSError as err:
        return f"cannot create files in {place} ({err.strerror or err})"
    return None
