"""Training and evaluation on the host: run directories, chunks, checkpoints and resume (`runs`), presets,
evaluation metrics and rendering. Imports the env and RL layers only."""
