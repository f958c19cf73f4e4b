"""Keeping an off-policy run's replay buffer (``--save-replay-buffer``) and continuing with it (``-i``): the files
(:mod:`sbagents.replay.buffer_files`) and the training extension (:mod:`sbagents.replay.extension`)."""
