"""Kuka iiwa pick-and-place environments on PyBullet (sim / robot / task split as in panda-gym)."""
