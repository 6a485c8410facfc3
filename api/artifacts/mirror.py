"""A local folder tree kept in step with a remote store, file by file.

The local tree (the data folder) is each machine's working copy; the remote store is the
record every machine shares. A file's key is its path relative to the local root, so
``<root>/jobs/<id>/run/checkpoint.pt`` is the object ``jobs/<id>/run/checkpoint.pt``.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path

from sparsesplat.api.artifacts.errors import ArtifactMissing
from sparsesplat.api.artifacts.remote import RemoteArtifacts
from sparsesplat.api.disk import PARTIAL_SUFFIX, is_partial


class Mirror:
    """Copies files between ``root`` and ``remote`` under the same relative names."""

    def __init__(self, root: Path, remote: RemoteArtifacts) -> None:
        """Mirror the tree under ``root`` into ``remote``."""
        self.root = root
        self.remote = remote

    def key(self, path: Path) -> str:
        """The object key of the local ``path`` (a path under the root)."""
        return path.relative_to(self.root).as_posix()

    def push(self, path: Path) -> None:
        """Store the local file ``path`` (whole: the object appears once complete).

        A large file goes up in parts, each read by opening the file again: the parts are
        read from a hard link made first, so a new version renamed over ``path`` meanwhile
        (the trainer's next checkpoint) cannot mix with this one."""
        snapshot = path.with_name(f"{path.name}.{uuid.uuid4().hex[:8]}{PARTIAL_SUFFIX}")
        try:
            os.link(path, snapshot)
        except FileNotFoundError:
            raise
        except OSError:  # no hard links on this filesystem: send the file itself
            self.remote.put_file(self.key(path), path)
            return
        try:
            self.remote.put_file(self.key(path), snapshot)
        finally:
            snapshot.unlink(missing_ok=True)

    def push_tree(self, folder: Path, include: Callable[[Path], bool] = lambda _: True) -> int:
        """Store the files under ``folder`` that ``include`` keeps and the store lacks or
        holds at another size (partial files never); returns how many were sent."""
        stored = self.remote.sizes(self.key(folder) + "/")
        sent = 0
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            if is_partial(path) or not include(path):
                continue
            if stored.get(self.key(path)) != path.stat().st_size:
                self.push(path)
                sent += 1
        return sent

    def pull(self, path: Path, fresh: bool = False) -> Path:
        """A local copy of ``path``: the one there (unless ``fresh``), else the stored one;
        ``ArtifactMissing`` when neither exists."""
        if not fresh and path.is_file():
            return path
        self.remote.get_file(self.key(path), path)
        return path

    def pull_tree(self, folder: Path) -> int:
        """Fetch the stored files under ``folder`` that are not here yet; returns how many.
        ``ArtifactMissing`` when the store holds nothing under it."""
        stored = self.remote.sizes(self.key(folder) + "/")
        if not stored:
            raise ArtifactMissing(f"nothing stored under {self.key(folder)} in "
                                  f"{self.remote.location}")  # fmt: skip
        fetched = 0
        for key in sorted(stored):
            path = self.root / key
            if not path.is_file() or path.stat().st_size != stored[key]:
                self.remote.get_file(key, path)
                fetched += 1
        return fetched

    def exists(self, path: Path) -> bool:
        """Whether ``path`` is here or stored."""
        return path.is_file() or self.remote.exists(self.key(path))

    def stored_bytes(self, folder: Path) -> int:
        """Bytes stored under ``folder``."""
        return sum(self.remote.sizes(self.key(folder) + "/").values())

    def newest(self, folder: Path) -> dict[str, float]:
        """For each folder stored under ``folder``: when its newest file was stored."""
        out: dict[str, float] = {}
        start = len(self.key(folder)) + 1
        for key, stored_at in self.remote.modified(self.key(folder) + "/").items():
            name = key[start:].split("/", 1)[0]
            out[name] = max(out.get(name, 0.0), stored_at)
        return out

    def delete_tree(self, folder: Path) -> None:
        """Remove what is stored under ``folder``."""
        self.remote.delete_prefix(self.key(folder) + "/")
