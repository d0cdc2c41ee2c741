"""The backends' disk cache: where a backend keeps what it derives or compiles (``cache_dir``), written atomically
(``write_cache_file``), within a size limit (``CROSSCHECK_CACHE_LIMIT``, default 1 GiB: the least recently used files
are removed past it; a hit marks its file used, ``used_cache_file``). Plumbing only, nothing numeric: backends reach it
through ``formalisms.interface``; ``crosscheck cache`` shows it and clears it."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

#: The environment variable of the cache's size limit (bytes, or with a suffix K, M, G: ``500M``).
CACHE_LIMIT_VARIABLE = "CROSSCHECK_CACHE_LIMIT"
#: The default size limit of the whole cache: 1 GiB.
CACHE_LIMIT = 1 << 30


def cache_root() -> Path:
    """The cache of every backend: ``$CROSSCHECK_CACHE``, else ``$XDG_CACHE_HOME/crosscheck`` (``~/.cache`` without
    it)."""
    return Path(os.environ.get("CROSSCHECK_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "crosscheck"))


def cache_dir(backend: str) -> Path:
    """Where a backend keeps what it derives or compiles: ``<cache_root>/<backend>`` (:func:`cache_root`)."""
    return cache_root() / backend


def cache_limit() -> int:
    """The cache's size limit in bytes: :data:`CACHE_LIMIT_VARIABLE` when set (``500M``, ``2G``, ``123456``), else
    :data:`CACHE_LIMIT`. A value that is not a size is a ValueError naming the variable."""
    text = os.environ.get(CACHE_LIMIT_VARIABLE, "").strip()
    if not text:
        return CACHE_LIMIT
    scale = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(text[-1].upper(), 1)
    try:
        value = float(text[:-1] if scale > 1 else text) * scale
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise ValueError(f"{CACHE_LIMIT_VARIABLE}={text!r} is not a size (bytes, or a number with K, M or G)")
    return int(value)


def cache_files(root: Path | None = None) -> list[tuple[float, int, Path]]:
    """Every file of the cache as ``(last use, size, path)``, least recently used first (the last use is the file's
    modification time, which :func:`used_cache_file` moves on every hit)."""
    files = []
    for path in (root or cache_root()).rglob("*"):
        with contextlib.suppress(OSError):
            stat = path.stat()
            if path.is_file():
                files.append((stat.st_mtime, stat.st_size, path))
    return sorted(files)


def used_cache_file(path: Path) -> None:
    """Mark a cache file as just used (a hit), so eviction (:func:`evict_cache`) removes it last."""
    with contextlib.suppress(OSError):
        os.utime(path)


#: Bytes this process has written to each cache root since it last measured the root's size (the measure walks the
#: whole cache, 60 ms for 6,500 files, so it is taken again only when the writes could have crossed the limit).
_WRITTEN: dict[Path, int] = {}
#: The size of each cache root as last measured by this process.
_MEASURED: dict[Path, int] = {}


def evict_cache(keep: Path | None = None, written: int = 0) -> int:
    """Keep the cache within :func:`cache_limit`: once it is over, remove the least recently used files down to 90 %
    of the limit (so that writes do not evict one file each); ``keep`` (the file just written) is never removed.
    ``written`` bytes just added: the cache is walked again only when its last measured size plus what this process
    has written since could exceed the limit, or this process has written a tenth of the limit since (other
    processes' writes are seen then: each can overshoot the limit by at most a tenth). Returns the bytes freed; files
    another process removes meanwhile are skipped."""
    root, limit = cache_root(), cache_limit()
    _WRITTEN[root] = _WRITTEN.get(root, 0) + written
    if root in _MEASURED and _MEASURED[root] + _WRITTEN[root] <= limit and _WRITTEN[root] <= limit // 10:
        return 0
    files = cache_files(root)
    total = sum(size for _, size, _ in files)
    freed = 0
    if total > limit:
        for _, size, path in files:
            if total - freed <= 0.9 * limit:
                break
            if path != keep:
                with contextlib.suppress(OSError):
                    path.unlink()
                    freed += size
    _MEASURED[root], _WRITTEN[root] = total - freed, 0
    return freed


def write_cache_file(path: Path, data: bytes) -> None:
    """Write a cache file atomically (a temporary file in the same directory renamed into place), so a reader never
    sees half of it and writers of the same entry do not disturb each other (the last one's file stays, and any is
    whole); then keep the cache within its limit (:func:`evict_cache`). A cache that cannot be written
    (``CROSSCHECK_CACHE`` a file, a read-only home, a full disk) only costs the work next time; the temporary file is
    removed."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(temporary, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        return
    evict_cache(keep=path, written=len(data))
