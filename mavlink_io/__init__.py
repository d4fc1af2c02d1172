"""Everything that touches MAVLink bytes: links, the rescue dialect, telemetry
decoding, clocks, senders, acknowledgements, signing and tlogs.

Of the project it imports only fusion (its types and error base): never the
companion, rescue-hq or the simulator, which all speak MAVLink through it."""
