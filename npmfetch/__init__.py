"""Files taken out of npm packages at set-up time, checked before they are used.

Used by the companion's person models (companion.vision.models) and by the
rescue-hq console's map library (hq.web.assets). A package's tarball is
downloaded once from the npm registry and checked against the registry's own
integrity string (``sha512-<base64>``); each file taken out of it is checked by
its sha256 and written atomically. Nothing here runs at run time: the programs
only read files that set-up put in place, and name those missing or altered.
Of the project it imports only fusion's error base.
"""

from __future__ import annotations

import base64
import hashlib
import io
import tarfile
import urllib.request
from dataclasses import dataclass
from pathlib import Path

from fusion.errors import RescueError

NPM_REGISTRY = "https://registry.npmjs.org"


class FetchError(RescueError):
    """A package could not be downloaded, or is not what it must be; one line."""


@dataclass(frozen=True)
class NpmPackage:
    name: str  # e.g. "@mediapipe/pose", "leaflet"
    version: str
    integrity: str  # the registry's "sha512-<base64>" of the tarball

    @property
    def tarball_url(self) -> str:
        base = self.name.split("/")[-1]
        return f"{NPM_REGISTRY}/{self.name}/-/{base}-{self.version}.tgz"


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def check_integrity(package: NpmPackage, tarball: bytes) -> None:
    algo, _, b64 = package.integrity.partition("-")
    digest = hashlib.new(algo, tarball).digest()
    if base64.b64encode(digest).decode() != b64:
        raise FetchError(
            f"{package.name}@{package.version}: the downloaded tarball does not match "
            "the registry's integrity string"
        )


def download(package: NpmPackage, timeout_s: float) -> bytes:
    """The package's tarball, checked against its integrity string."""
    try:
        with urllib.request.urlopen(package.tarball_url, timeout=timeout_s) as resp:
            data: bytes = resp.read()
    except OSError as exc:
        raise FetchError(
            f"cannot download {package.tarball_url}: {exc}; these files come from the npm "
            "registry, which this machine must reach once during set-up"
        ) from None
    check_integrity(package, data)
    return data


def member(tarball: bytes, path: str, package: NpmPackage) -> bytes:
    """One file of a package's tarball (``package/...``)."""
    with tarfile.open(fileobj=io.BytesIO(tarball), mode="r:gz") as tar:
        try:
            f = tar.extractfile(path)
        except KeyError:
            f = None
        if f is None:
            raise FetchError(f"{package.name}@{package.version} has no file {path}")
        return f.read()


def is_installed(path: Path, sha256: str) -> bool:
    try:
        return sha256_hex(path.read_bytes()) == sha256
    except OSError:
        return False


def install(path: Path, data: bytes, sha256: str, what: str) -> None:
    """Write ``data`` to ``path`` (atomically) after checking its sha256."""
    if sha256_hex(data) != sha256:
        raise FetchError(f"{what} has an unexpected sha256; refusing to install it")
    tmp = path.with_suffix(path.suffix + ".part")
    tmp.write_bytes(data)
    tmp.replace(path)
