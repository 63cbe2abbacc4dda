"""CPU speed: XLA's CPU fusion emitters make MJX 25-1000x slower (docs/benchmarks.md), and one XLA
CPU device runs a vmapped MJX step on about one core.

`enable_fast_cpu_flags()` merges `--xla_cpu_use_fusion_emitters=false` into XLA_FLAGS, keeping
every flag the user already set (a user's own value of this flag wins). XLA reads XLA_FLAGS when
its backend starts, so this must run before the first JAX computation; `import match_jax` calls it.
The flag only affects the CPU backend. jaxlib 0.11 removed it, and XLA aborts at backend start on
an unknown flag ("Unknown flag in XLA_FLAGS", seen on the lent GPUs' jax 0.11.2), so it is only set
for jaxlib < 0.11.

`enable_host_devices()` gives JAX one CPU device per usable core (`JAX_NUM_CPU_DEVICES`), so the
trainer and the evaluator can shard their envs over the cores: measured on the 2-core machine, a
128-env contact-rich rollout ran 1.57x faster sharded over 2 CPU devices than on one, and an
unsharded program runs as before on device 0 (docs/benchmarks.md). A user's own
`JAX_NUM_CPU_DEVICES` or `--xla_force_host_platform_device_count` wins; `JAX_NUM_CPU_DEVICES=1`
turns it off. It only affects the CPU backend (on a GPU machine `jax.devices()` is still the GPUs).
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
DEVICE_COUNT_ENV = "JAX_NUM_CPU_DEVICES"
DEVICE_COUNT_FLAG = "--xla_force_host_platform_device_count"


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


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask, else os.cpu_count())."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS / Windows
        return os.cpu_count() or 1


def host_device_count(environ, cores: int) -> int | None:
    """How many CPU devices to ask JAX for: None if the user already chose (either setting), else `cores`."""
    if environ.get(DEVICE_COUNT_ENV) or DEVICE_COUNT_FLAG in environ.get("XLA_FLAGS", ""):
        return None
    return max(1, int(cores))


def enable_host_devices() -> None:
    """One JAX CPU device per usable core unless the user set the count; a no-op once JAX's backend runs."""
    count = host_device_count(os.environ, usable_cores())
    if count is None or _backend_started():
        return
    if "jax" in sys.modules:  # imported, not started: the env var was already read, set the config
        import jax

        jax.config.update("jax_num_cpu_devices", count)
    else:
        os.environ[DEVICE_COUNT_ENV] = str(count)
