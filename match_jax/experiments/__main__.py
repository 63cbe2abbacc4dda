"""`python -m match_jax.experiments`: the suite's pipeline (`match_jax.experiments.pipeline`)."""

import sys

from match_jax.experiments.pipeline import main

sys.exit(main())
