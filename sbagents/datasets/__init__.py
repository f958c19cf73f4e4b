"""Datasets of episodes in Minari's format (the ``data`` extra: ``pip install 'sbagents[data]'``), which d3rlpy,
TorchRL and AgileRL read: :mod:`sbagents.datasets.writing` turns recorded episodes into a dataset, written atomically
under ``MINARI_DATASETS_PATH`` (Minari's default root otherwise). ``python -m sbagents.collect`` records them
(:mod:`sbagents.pipeline.collecting`).
"""
