"""rescue-hq, the ground side: receives, acknowledges and merges the robots' reports,
shows them and hands them on. By role:

- in from the robots: ``wire`` (the dialect's adapter), ``sources`` (a decoder per
  link and address), ``intake`` (reports), ``pictures``, ``coverage``; out to them:
  ``sending``, ``actions`` (operator actions, resent until acknowledged);
- kept: ``registry`` (one SQLite file; ``registry_file``, ``registry_rows``,
  ``records``, ``epoch``, ``unstored``);
- merged and shown: ``merge``, ``view``, ``table``, ``output``, ``sbs`` (QGC's map),
  ``export``, ``web`` (the browser console);
- run: ``app`` (the loop), ``cli`` with ``cli_run`` and ``cli_registry``.

Imports fusion, mavlink_io and npmfetch; never the companion or the simulator
(tests/test_layers.py).
"""
