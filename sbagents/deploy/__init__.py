"""Deployment: ONNX export (:mod:`~sbagents.deploy.onnx_export`, :mod:`~sbagents.deploy.parity`,
:mod:`~sbagents.deploy.exporting`) and the torch-free decision loop (:mod:`~sbagents.deploy.serving`).

This package imports nothing on its own: ``serving`` must load with only numpy and onnxruntime installed.
"""
