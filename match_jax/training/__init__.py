"""Training and evaluation on the host: run directories, chunks, checkpoints and resume (`runs`), presets
and command-line overrides, evaluation metrics and rendering. Imports the env and RL layers only."""
