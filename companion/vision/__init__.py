"""Vision: what each camera's frame shows. The colour detectors (``backends.py``
builds the configured one: people, classic, dnn, hog), dark-scene enhancement, the
thermal detector (``thermal.py``), and each find's visibility and urgency
(``visibility.py``). See docs/VISION.md.

Pure per-frame perception on arrays: imports the config, fusion's types and the
camera model, never a source, a link, the service or the reporting.
"""
