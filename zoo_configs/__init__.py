"""RL Zoo format hyperparameter files shipped with sbagents (one YAML file per algorithm)."""
