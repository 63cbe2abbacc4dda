"""The experiment suite: its runs (`suite`), the train-evaluate-report pipeline (`pipeline`, also
`python -m match_jax.experiments`), the report, its statistics (`claims`) and figures (`plots`)."""
