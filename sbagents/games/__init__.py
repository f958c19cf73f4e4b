"""Turn-based games (PettingZoo AEC envs with action masks): self-play, opponents, matches, ratings."""
