"""CPU speed: XLA's CPU fusion emitters make MJX 25-1000x slower (shared/DESIGN.md).

`enable_fast_cpu_flags()` merges `--xla_cpu_use_fusion_emitters=false` into XLA_FLAGS, keeping
every flag the user already set (a user's own value of this flag wins). XLA reads XLA_FLAGS when
its backend starts, so this must run before the first JAX computation; `import match_jax` calls it.
The flag only affects the CPU backend. jaxlib 0.11 removed it, and XLA aborts at backend start on
an unknown flag ("Unknown flag in XLA_FLAGS", seen on the lent GPUs' jax 0.11.2), so it is only set
for jaxlib < 0.11.
"""

from __future__ import annotations

import os
import re
import sys
import warnings
from importlib import metadata

CPU_FLAG = "--xla_cpu_use_fusion_emitters"
CPU_FLAG_VALUE = f"{CPU_FLAG}=false"
LAST_JAXLIB_WITH_FLAG = (0, 10)  # jaxlib 0.11 dropped the flag


def flag_supported(jaxlib_version: str | None) -> bool:
    """Whether this jaxlib's XLA knows the CPU fusion flag (unknown or unparsable version: assume yes)."""
    match = re.match(r"(\d+)\.(\d+)", jaxlib_version or "")
    return match is None or (int(match[1]), int(match[2])) <= LAST_JAXLIB_WITH_FLAG


def _jaxlib_version() -> str | None:
    try:
        return metadata.version("jaxlib")
    except metadata.PackageNotFoundError:  # pragma: no cover - jax always brings jaxlib
        return None


def merged_xla_flags(existing: str | None) -> str:
    """XLA_FLAGS with the CPU fusion flag added unless the user already set that flag."""
    existing = (existing or "").strip()
    if CPU_FLAG in existing:
        return existing
    return f"{existing} {CPU_FLAG_VALUE}".strip()


def _backend_started() -> bool:
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge

        return bool(getattr(xla_bridge, "_backends", {}))
    except Exception:  # pragma: no cover - private API moved
        return False


def enable_fast_cpu_flags() -> None:
    """Merge the CPU flag into XLA_FLAGS; warn if a JAX backend already started without it."""
    if not flag_supported(_jaxlib_version()):
        return
    new = merged_xla_flags(os.environ.get("XLA_FLAGS"))
    if new == os.environ.get("XLA_FLAGS", "").strip():
        return
    if _backend_started():
        warnings.warn(
            "match_jax was imported after JAX started its backend, so XLA_FLAGS cannot take "
            f"{CPU_FLAG_VALUE}; MJX on CPU will be 25-1000x slower. Import match_jax first or "
            f"export XLA_FLAGS={CPU_FLAG_VALUE}.",
            stacklevel=3,
        )
        return
    os.environ["XLA_FLAGS"] = new
