"""match_jax: hybrid position/force control policies for fragile peg-in-hole, in JAX + MuJoCo-MJX.

Importing the package sets XLA's fast CPU flag and one JAX CPU device per core (see `match_jax._xla`)
before JAX starts.
"""

from match_jax._xla import enable_fast_cpu_flags as _enable_fast_cpu_flags
from match_jax._xla import enable_host_devices as _enable_host_devices

_enable_fast_cpu_flags()
_enable_host_devices()

__version__ = "0.1.0"
