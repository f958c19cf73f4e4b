"""Baselines every env is compared with: uniform random actions (:class:`~sbagents.baselines.policies.RandomPolicy`)
and the scripted experts of the book's envs (:mod:`sbagents.baselines.experts`, the Kuka scripts), which
``python -m sbagents.evaluate --policy random|scripted`` plays (:func:`sbagents.pipeline.baselines.evaluate_baseline`).

A scripted expert is a *controller*: built on one env (it may read the env's true state), ``reset()`` at each
episode's first step, ``act(obs)`` one action; :class:`~sbagents.baselines.policies.ControllerPolicy` runs one per
copy of a VecEnv with SB3's ``predict`` signature, so every evaluation path plays it like a model.
:data:`sbagents.registration.SCRIPTED_POLICIES` names each env's controller by import path.
"""
