"""What the companion keeps on disk: one SQLite file (``store``), read back at
start-up or set aside when it is bad (``recovery``), and written on every commit of
the processing thread while the service runs (``ledger``).

Imports the reporting state it saves (the policy, the pictures, the announcer) and
fusion's tracker snapshot; never the service, the commands, a link or a camera.
"""
