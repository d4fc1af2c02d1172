"""What the running HQ counts; `rescue-hq run` logs it when it stops."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Counters:
    reports: int = 0
    duplicates: int = 0
    rejected: int = 0  # reports refused for unusable values (acknowledged REJECTED)
    refused: int = 0  # other messages refused for unusable values
    signature_refused: int = 0  # unsigned or badly signed where a signature is required
    acks_sent: int = 0
    store_failures: int = 0
    actions_sent: int = 0
    actions_acked: int = 0
    actions_rejected: int = 0
    foreign_tunnels: int = 0
    exports: int = 0
    inbox_dropped: int = 0  # datagrams dropped because the main thread was behind
    sources_forgotten: int = 0  # decoders dropped: silent too long, or too many sources
