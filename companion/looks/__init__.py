"""Closer looks: short GUIDED detours to a candidate the companion cannot settle.
``choose`` picks the candidate and the viewpoint, ``machine`` steps one look from
leaving the route to resuming it, with ``steps``' values (all pure, no I/O), ``run`` sends and hears the
steps on the vehicle link. docs/LOOKS.md.

Imports the config, fusion and ``mavlink_io.guided``; never the service, the
storage or the reporting (the service hands it what it needs).
"""
