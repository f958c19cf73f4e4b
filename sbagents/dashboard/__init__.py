"""The operator's dashboard (``python -m sbagents.dashboard -f logs``; ``pip install 'sbagents[dashboard]'``).

A read-only Flask app over the run dirs that ``train`` writes: :func:`~sbagents.dashboard.app.create_app` for any
WSGI server, :func:`~sbagents.dashboard.server.serve` for the CLI's own server, and
:func:`~sbagents.dashboard.logregistry.open_log` for paging transparency logs of any size from Python.
"""

from __future__ import annotations

from sbagents.dashboard.server import DashboardOptions, serve

__all__ = ["DashboardOptions", "serve"]
