"""``crosscheck cache``: where the backends' derivations and compiled code are kept, how much of the limit they use,
and ``--clear`` to empty it (``formalisms.cache``: ``cache_root``, the size limit ``CROSSCHECK_CACHE_LIMIT``, least
recently used files evicted past it)."""

from __future__ import annotations

import shutil

from formalisms.cache import CACHE_LIMIT_VARIABLE, cache_files, cache_limit, cache_root


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB"):
        if n < 1024:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.2f} GiB"


def cmd_cache(args) -> int:
    root = cache_root()
    if args.clear:
        freed = sum(size for _, size, _ in cache_files(root)) if root.exists() else 0
        shutil.rmtree(root, ignore_errors=True)
        print(f"cleared {root} ({_size(freed)})")
        return 0
    files = cache_files(root) if root.exists() else []
    print(f"cache: {root}\nsize: {_size(sum(size for _, size, _ in files))} in {len(files)} files, limit "
          f"{_size(cache_limit())} ({CACHE_LIMIT_VARIABLE}; least recently used files are removed past it)")
    for backend in sorted({p.relative_to(root).parts[0] for _, _, p in files}):
        part = [size for _, size, p in files if p.relative_to(root).parts[0] == backend]
        print(f"  {backend}: {_size(sum(part))} in {len(part)} files")
    return 0


def add_parser(sub) -> None:
    """The ``cache`` subcommand on ``sub``."""
    parser = sub.add_parser("cache", help="show the derivation cache (where, how large, its limit) or --clear it")
    parser.add_argument("--clear", action="store_true", help="remove every cached derivation and compiled library")
    parser.set_defaults(run=cmd_cache)
