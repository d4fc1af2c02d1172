"""The running service (``rescue-companion run``) and its threads: the links to the
vehicle and the ground (``links``), the camera threads (``capture``), the processing
thread (``processing``, with the ground's requests in ``ground``), the reporter thread
(``reporter``, what it says of the robot in ``status``), the live video, the
parameters QGC edits (``params``), systemd's notify protocol and the stop signals;
``run.Service`` starts and stops them all.

The only package that wires threads and sockets together: nothing else in the
companion imports it, except ``commands``.
"""
