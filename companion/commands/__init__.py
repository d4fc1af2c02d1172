"""The command line, ``rescue-companion``: ``cli`` parses it and dispatches to the
service (``run``), ``detect`` (the perception step on image, video and thermal
files), ``replay`` (the live pipeline on a recorded mission) and the mission map
PNG they draw (``missionmap``).

The top of the companion: it may import any of it; nothing in the companion imports
it.
"""
