"""JAX's persistent compilation cache for the command-line tools (train.py, eval.py, the suite).

On CPU nearly all the waiting is XLA compilation of the MJX programs; with the cache a second run of
the same program loads it instead of compiling. `enable()` points JAX at `default_dir()` (under the
user's cache directory) unless the user chose a directory (JAX_COMPILATION_CACHE_DIR) or turned the
cache off with MATCH_JAX_COMPILATION_CACHE=0. Library imports do not turn it on.
"""

from __future__ import annotations

import os
import pathlib

OFF_ENV = "MATCH_JAX_COMPILATION_CACHE"
JAX_DIR_ENV = "JAX_COMPILATION_CACHE_DIR"


def default_dir(environ=os.environ) -> pathlib.Path:
    """$XDG_CACHE_HOME/match_jax/jax, or ~/.cache/match_jax/jax."""
    base = environ.get("XDG_CACHE_HOME") or str(pathlib.Path.home() / ".cache")
    return pathlib.Path(base) / "match_jax" / "jax"


def cache_dir(environ=os.environ) -> pathlib.Path | None:
    """The directory to use: None when turned off, the user's JAX_COMPILATION_CACHE_DIR, else the default."""
    if environ.get(OFF_ENV, "").strip().lower() in ("0", "false", "off", "no"):
        return None
    if environ.get(JAX_DIR_ENV):
        return pathlib.Path(environ[JAX_DIR_ENV])
    return default_dir(environ)


def enable(environ=os.environ) -> pathlib.Path | None:
    """Turn the persistent cache on (programs that took >= 1 s to compile); returns its directory.

    A cache directory already set in this process (jax.config) is kept."""
    path = cache_dir(environ)
    if path is None:
        return None
    import jax

    if jax.config.jax_compilation_cache_dir:
        return pathlib.Path(jax.config.jax_compilation_cache_dir)

    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    return path


def describe() -> str:
    """Whether JAX's persistent compilation cache is on in this process, and its directory, in a few words:
    'compilation cache on: DIR' or 'compilation cache off'."""
    import jax

    path = jax.config.jax_compilation_cache_dir
    if path and jax.config.jax_enable_compilation_cache:
        return f"compilation cache on: {path}"
    return "compilation cache off"
