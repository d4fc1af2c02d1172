"""The program on the Pi, ``rescue-companion``. By role:

- ``sources``: the colour and thermal cameras behind one interface;
- ``vision``: detectors, visibility and urgency on one frame;
- ``pipeline``: one frame through pose, vision, geolocation and tracking, and
  ``coverage``: where each frame looked (both shared by the service and replay);
- ``reporting``: what is said to whom and when; ``storage``: what is kept on disk;
- ``looks``: closer looks; ``service``: the running service and its threads;
- ``commands``: the command line; ``config`` (read by ``config_load``),
  ``calibration``, ``errors``: shared.

Each subpackage's docstring says what it must not import (tests/test_layers.py
holds them to it). Math lives in ``fusion``, MAVLink bytes in ``mavlink_io``.
"""
