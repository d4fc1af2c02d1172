"""Everything that touches MAVLink bytes: links, the rescue dialect, telemetry
decoding, clocks, senders, acknowledgements, signing and tlogs."""
