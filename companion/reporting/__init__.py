"""What the companion tells whom, and when: the reporting policy (``policy``: when a
victim is reported to the HQ), what people hear (``announcements``), the evidence
pictures (``pictures``), the searched-area map's transport (``coverage_sender``) and
the annotated video for QGC (``video``).

Decisions and encodings only: the service's reporter thread sends them. Keeps its own
progress through ``storage.store``; never imports the service, the commands or a
link.
"""
