"""The console's map library, Leaflet (BSD-2-Clause), vendored at set-up time.

``rescue-hq assets fetch`` (run by make) takes leaflet.js, leaflet.css and its
LICENSE out of the npm registry's ``leaflet`` tarball, checked against the
registry's sha512 integrity string and each file's sha256 (npmfetch, the same way
the companion's person models come), into ``<sys.prefix>/share/rescue-companion/
web``, or ``RESCUE_HQ_ASSET_DIR``. The console serves them from there; nothing is
fetched at run time, and the page says so when they are missing.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

import npmfetch
from npmfetch import FetchError, NpmPackage

LEAFLET = NpmPackage(
    "leaflet",
    "1.9.4",
    "sha512-nxS1ynzJOmOlHp+iL3FyWqK89GtNL8U8rvlMOsQdTTssxZwCXh8N2NB3GDQOL+YR3XnWyZAxwQixURb+FA74PA==",
)


@dataclass(frozen=True)
class AssetFile:
    name: str  # file name in the asset folder (and in the URL /vendor/<name>)
    member: str  # path inside the tarball
    sha256: str
    media_type: str


ASSETS: dict[str, AssetFile] = {
    a.name: a
    for a in (
        AssetFile(
            "leaflet.js",
            "package/dist/leaflet.js",
            "db49d009c841f5ca34a888c96511ae936fd9f5533e90d8b2c4d57596f4e5641a",
            "text/javascript",
        ),
        AssetFile(
            "leaflet.css",
            "package/dist/leaflet.css",
            "a7837102824184820dfa198d1ebcd109ff6d0ff9a2672a074b9a1b4d147d04c6",
            "text/css",
        ),
        AssetFile(
            "LEAFLET-LICENSE.txt",
            "package/LICENSE",
            "53e8dc25862014e4324741ca18fbe3611e11d42ef69f59f86ea8c5389647d4cb",
            "text/plain",
        ),
    )
}
FETCH_HINT = "run `rescue-hq assets fetch` (make does it on set-up)"


def default_asset_dir() -> Path:
    env = os.environ.get("RESCUE_HQ_ASSET_DIR")
    if env:
        return Path(env)
    return Path(sys.prefix) / "share" / "rescue-companion" / "web"


def verify(asset_dir: Path | None = None) -> list[str]:
    """One line per asset that is missing or altered (empty: all good)."""
    folder = asset_dir if asset_dir is not None else default_asset_dir()
    return [
        f"{folder / a.name} is missing or altered: {FETCH_HINT}"
        for a in ASSETS.values()
        if not npmfetch.is_installed(folder / a.name, a.sha256)
    ]


def fetch(asset_dir: Path | None = None, timeout_s: float = 120.0) -> list[Path]:
    """Put every asset in ``asset_dir``; download the tarball only when one is missing.

    FetchError (one line) when the registry cannot be reached or a file is altered.
    """
    folder = asset_dir if asset_dir is not None else default_asset_dir()
    folder.mkdir(parents=True, exist_ok=True)
    missing = [a for a in ASSETS.values() if not npmfetch.is_installed(folder / a.name, a.sha256)]
    if not missing:
        return []
    tarball = npmfetch.download(LEAFLET, timeout_s)
    written = []
    for a in missing:
        data = npmfetch.member(tarball, a.member, LEAFLET)
        npmfetch.install(
            folder / a.name, data, a.sha256, f"{a.member} of leaflet@{LEAFLET.version}"
        )
        written.append(folder / a.name)
    return written


__all__ = ["ASSETS", "LEAFLET", "AssetFile", "FetchError", "default_asset_dir", "fetch", "verify"]
