"""The RL core: the four methods' action distributions, the SimBa networks, the PPO and SSL losses, and
the jitted PPO trainer (rollout, GAE and update in one XLA program). Imports the env layer only."""
