"""On-disk cache of derivations, stored as authenticated text.

A derivation is keyed by the method, its options, the oscillator's equation (``srepr``) and
parameter values, perturb's version and a hash of the sources of the method's module and of
every perturb module it reaches (the shared engines it calls) — so editing a method, or an
engine it uses, invalidates its entries.

An entry is JSON: one table of expression nodes shared by every field (the derivation steps
repeat the same symbols and subexpressions thousands of times), each node a whitelisted
constructor name with references to earlier nodes, or a literal leaf (symbol, number,
constant). Reading it calls only those constructors, unevaluated, so a hit rebuilds exactly
the trees the method returned in milliseconds — parsing ``srepr`` text costs tenths of a
second for a long derivation. The codec is :mod:`perturb.io.serialize`'s
(:func:`~perturb.io.serialize.approximation_to_table`,
:func:`~perturb.io.serialize.approximation_from_table`, with the same closed vocabulary as
its srepr reader); this module adds the cache key, the authentication and the files. An
approximation whose rebuilt form would differ from it (an expression type the table does not
know) is not stored.

Trust
-----
The cache folder may be shared (``PERTURB_CACHE_DIR`` on a shared disk, a CI cache restored
from another branch), so whoever can write it must not be able to make perturb run code or
return a wrong answer. Two independent checks, both before anything is built:

1. **Authentication: HMAC-SHA256 with a per-user secret key.** An entry file is the JSON
   object ``{"perturb-cache": <layout>, "hmac": "<hex>", "entry": <entry>}``, checked on its
   bytes before anything is parsed; the HMAC covers the layout, the entry's cache key (its
   file name — an entry moved to another key fails) and every byte of ``<entry>``, so an
   edited number, symbol or step is detected. The key is
   ``$PERTURB_CACHE_KEY`` when set (a secret of at least 16 characters), else 32 random
   bytes in ``$XDG_CONFIG_HOME/perturb/cache-key`` (default ``~/.config/perturb/cache-key``):
   created on first use with mode 0600 in a 0700 folder, and refused — caching is then off,
   with a warning — if it is a link, readable or writable by others, owned by another user,
   or inside the cache folder. A content hash checked against the file name would not do:
   the name hashes the *inputs* of a derivation, which anyone can compute, so a forger
   could store any content under it; only a secret the forger lacks authenticates.
2. **A closed vocabulary** (:class:`perturb.io.serialize.Vocabulary`, the one the JSON codec
   reads ``perturb derive --json`` files with): constructor names from
   :data:`perturb.io.serialize.CLASSES`, symbol names the oscillator declares or the engines
   use, function names the engines use, numbers as bounded finite numbers (no ``NaN`` or
   ``Infinity`` in the JSON). This holds even for an entry authenticated by a leaked key.

An entry that fails either check — tampered, written with another key, truncated, from
another layout, outside the vocabulary — is reported with a :class:`CacheWarning` naming the
file, recomputed and overwritten: never executed, never trusted.

Location: ``$PERTURB_CACHE_DIR``, else ``$XDG_CACHE_HOME/perturb``, else
``~/.cache/perturb``; ``PERTURB_CACHE=0`` switches caching off.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import inspect
import json
import os
import re
import secrets
import stat
import sys
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import sympy as sp

from perturb.approximation import Approximation
from perturb.io.serialize import (
    FORMAT_VERSION,
    UnsupportedExpression,
    approximation_from_table,
    approximation_to_table,
)
from perturb.model.oscillator import Oscillator

__all__ = [
    "CacheWarning",
    "authenticate",
    "cache_dir",
    "cache_key_file",
    "cached_derivation",
    "derivation_key",
    "is_inside",
    "reset_key_state",
    "seal_entry",
]

# Layout of an entry (bump to orphan older entries): 2 = node table, tagged options;
# 3 = authenticated (header line with an HMAC), read through serialize's vocabulary.
_ENTRY_VERSION = 3
_MAGIC = b"perturb-cache"
_MAX_BYTES = 512 * 2**20  # an entry larger than this is not read


class CacheWarning(UserWarning):
    """A cache entry (or the cache key) was not trusted: the derivation is recomputed."""


def cache_dir() -> Path:
    """The cache folder (created on first write)."""
    if os.environ.get("PERTURB_CACHE_DIR"):
        return Path(os.environ["PERTURB_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "perturb"


def cache_key_file() -> Path:
    """The file holding this user's secret cache key (used unless ``PERTURB_CACHE_KEY`` is set):
    ``$XDG_CONFIG_HOME/perturb/cache-key``, default ``~/.config/perturb/cache-key``."""
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "perturb" / "cache-key"


def _engine_modules(fn: Callable[..., Any]) -> list[Any]:
    """The module of ``fn`` and every perturb module it reaches through its global names
    (modules, and functions or classes defined in one), transitively: a method's result
    depends on the shared engines it calls (the L-P series engine, the caveats, the Fourier
    symbols), not only on its own file."""
    first = sys.modules.get(getattr(fn, "__module__", "") or "")
    if first is None:
        return []
    seen = {first.__name__: first}
    todo = [first]
    while todo:  # bounded: each perturb module is visited once
        module = todo.pop()
        for value in list(vars(module).values()):
            name = value.__name__ if inspect.ismodule(value) else getattr(value, "__module__", None)
            if not isinstance(name, str) or not name.startswith("perturb.") or name in seen:
                continue
            dep = sys.modules.get(name)
            if dep is not None:
                seen[name] = dep
                # a package's names include whichever submodules happen to be imported, so
                # its own source counts but its names are not followed (a stable key)
                if not hasattr(dep, "__path__"):
                    todo.append(dep)
    return [seen[name] for name in sorted(seen)]


def _source_hash(fn: Callable[..., Any]) -> str:
    """A hash of the sources of :func:`_engine_modules` of ``fn``: editing the method or an
    engine it uses changes the cache key."""
    h = hashlib.sha256()
    modules = _engine_modules(fn)
    try:
        for module in modules:
            h.update(module.__name__.encode() + b"\0" + inspect.getsource(module).encode())
    except (OSError, TypeError):
        modules = []
    if not modules:
        h = hashlib.sha256(repr(fn).encode())
    return h.hexdigest()[:16]


def derivation_key(method: str, fn: Callable[..., Any], osc: Oscillator, options: dict) -> str:
    """The cache key: a hash of everything the derivation depends on."""
    from perturb import __version__

    payload = {
        "format": FORMAT_VERSION,
        "entry": _ENTRY_VERSION,
        "version": __version__,
        "method": method,
        "source": _source_hash(fn),
        "options": {k: repr(v) for k, v in sorted(options.items())},
        "equation": sp.srepr(osc.equation),
        "params": {k: repr(v) for k, v in sorted(osc.params.items())},
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


# ------------------------------------------------------------------------- the secret key --
class _NoKey(Exception):
    """No trustworthy key: the cache is not used."""


_KEYS: dict[tuple[str | None, str, str], bytes] = {}
_WARNED: set[str] = set()


def is_inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies inside it, links resolved (``False`` when either
    cannot be resolved).  The test that refuses a key file inside the cache folder."""
    try:
        p, f = path.resolve(), folder.resolve()
    except (OSError, RuntimeError):
        return False
    return p == f or f in p.parents


def _create_key(path: Path) -> None:
    """A new random key at ``path`` (0600 in a 0700 folder), unless one appears meanwhile."""
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(secrets.token_hex(32) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, path)  # fails if another process created the key first: theirs wins
        except FileExistsError:
            pass
        except OSError:  # a file system without hard links
            if not path.exists():
                os.replace(tmp, path)
    finally:
        try:
            tmp.unlink()
        except OSError:
            pass


def _read_key(path: Path) -> bytes:
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0)
    fd = os.open(path, flags)
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise _NoKey(f"the key file {str(path)!r} is not a regular file")
        if hasattr(os, "getuid") and st.st_uid != os.getuid():
            raise _NoKey(f"the key file {str(path)!r} belongs to another user")
        if os.name == "posix" and st.st_mode & 0o077:
            raise _NoKey(
                f"the key file {str(path)!r} is accessible to other users (mode "
                f"{stat.S_IMODE(st.st_mode):o}): `chmod 600` it, or delete it to make a new one"
            )
        text = fh.read(256).strip()
    try:
        key = bytes.fromhex(text.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) < 32:
        raise _NoKey(f"the key file {str(path)!r} does not hold a key: delete it to make one")
    return key


def _secret() -> bytes:
    """This user's cache key (see the module docstring); raises :class:`_NoKey`."""
    env = os.environ.get("PERTURB_CACHE_KEY")
    path = cache_key_file()
    memo = (env, str(path), str(cache_dir()))
    if memo in _KEYS:
        return _KEYS[memo]
    if env is not None:
        if len(env) < 16:
            raise _NoKey("PERTURB_CACHE_KEY is set but shorter than 16 characters")
        key = hashlib.sha256(b"perturb-cache-key\0" + env.encode()).digest()
    else:
        if not path.is_absolute():
            raise _NoKey(
                f"no home folder for the key file ({str(path)!r}): set XDG_CONFIG_HOME or "
                "PERTURB_CACHE_KEY"
            )
        if is_inside(path, cache_dir()):
            raise _NoKey(
                f"the key file {str(path)!r} lies inside the cache folder {str(cache_dir())!r}, "
                "which others may be able to read"
            )
        key = b""
        for _ in range(3):  # created by a concurrent process between the two steps: read it
            try:
                key = _read_key(path)
                break
            except FileNotFoundError:
                try:
                    _create_key(path)
                except OSError as exc:
                    raise _NoKey(f"cannot create the key file {str(path)!r}: {exc}") from None
            except OSError as exc:
                raise _NoKey(f"cannot read the key file {str(path)!r}: {exc}") from None
        if not key:
            raise _NoKey(f"cannot create the key file {str(path)!r}")
    _KEYS[memo] = key
    return key


def authenticate(label: str, data: bytes) -> str | None:
    """HMAC-SHA256 (hex) of ``data`` bound to ``label`` under this user's cache key (module
    docstring), for other files perturb reads back (sweep checkpoints); ``None`` when no
    trustworthy key is available."""
    try:
        key = _secret()
    except _NoKey:
        return None
    msg = b"perturb/%s\n" % label.encode() + data
    return hmac.new(key, msg, hashlib.sha256).hexdigest()


def reset_key_state() -> None:
    """Forget the keys read in this process and the reasons already warned about, so the next
    use reads the key (file or ``PERTURB_CACHE_KEY``) again and warns afresh — after the key,
    its file or the environment changed (tests).  Nothing on disk changes."""
    _KEYS.clear()
    _WARNED.clear()


def seal_entry(name: str, body: bytes) -> bytes | None:
    """The bytes of a cache entry file holding ``body`` (the entry's JSON) under the cache key
    ``name`` (its file name without ``.json``), authenticated with this user's key — exactly
    what :func:`cached_derivation` writes; ``None`` when no trustworthy key is available.

    Only the holder of the secret key can call it usefully (as with :func:`authenticate`), so
    it forges nothing that holder could not already write; such an entry is still read only
    through the closed vocabulary (module docstring, check 2).
    """
    try:
        key = _secret()
    except _NoKey:
        return None
    return _seal(key, name, body)


def _mac(key: bytes, name: str, body: bytes) -> bytes:
    msg = b"%s/%d\n%s\n" % (_MAGIC, _ENTRY_VERSION, name.encode()) + body
    return hmac.new(key, msg, hashlib.sha256).hexdigest().encode()


def _seal(key: bytes, name: str, body: bytes) -> bytes:
    # still one JSON object: {"perturb-cache": <layout>, "hmac": "<hex>", "entry": <body>}
    return b'{"%s":%d,"hmac":"%s","entry":' % (_MAGIC, _ENTRY_VERSION, _mac(key, name, body)) + (
        body + b"}"
    )


class _Rejected(Exception):
    """An entry that is not trusted (the message says why)."""


_HEAD = b'{"%s":%d,"hmac":"' % (_MAGIC, _ENTRY_VERSION)
_BODY_AT = len(_HEAD) + 64 + len(b'","entry":')


def _open(raw: bytes, key: bytes, name: str) -> bytes:
    """The entry's JSON body, if the file's HMAC authenticates it under ``name`` (checked on
    the bytes, before any parsing)."""
    if not raw.startswith(_HEAD):
        m = re.match(rb'\{\s*"perturb-cache"\s*:\s*(\d{1,9})', raw)
        if m is None:
            raise _Rejected("it is not an authenticated perturb cache entry")
        if int(m[1]) != _ENTRY_VERSION:
            raise _Rejected(f"it is of layout {int(m[1])}, not {_ENTRY_VERSION}")
        raise _Rejected("it was edited (it is not laid out as perturb writes entries)")
    mac, sep = raw[len(_HEAD) : len(_HEAD) + 64], raw[len(_HEAD) + 64 : _BODY_AT]
    body = raw[_BODY_AT:-1]
    if sep != b'","entry":' or not raw.endswith(b"}"):
        raise _Rejected("it is not an authenticated perturb cache entry")
    if not hmac.compare_digest(mac, _mac(key, name, body)):
        raise _Rejected(
            "it failed authentication (edited, truncated, moved from another entry, or written "
            "with another key)"
        )
    return body


# ------------------------------------------------------------------------------ entries --
def _entry(approx: Approximation) -> dict[str, Any]:
    """The entry body: the node-table description of :mod:`perturb.io.serialize` and the
    layout version (the HMAC covers both)."""
    return {**approximation_to_table(approx), "entry": _ENTRY_VERSION}


def _approximation(data: Any, osc: Oscillator, where: str = "cache entry") -> Approximation:
    """The approximation an entry describes; raises ``ValueError``/``ParseError`` (and,
    for a malformed entry, ``KeyError``/``TypeError``) for anything outside the vocabulary."""
    if not isinstance(data, dict) or data.get("entry") != _ENTRY_VERSION:
        raise ValueError("an entry of another layout")
    return approximation_from_table(data, osc, where)


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number")


def _read(path: Path, name: str, key: bytes, osc: Oscillator) -> Approximation | None:
    """The entry at ``path`` if it exists and is trusted; ``None`` if absent. An entry that is
    not trusted is reported (:class:`CacheWarning` naming the file) and ``None`` returned."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read(_MAX_BYTES + 1)
    except FileNotFoundError:
        return None
    except OSError as exc:
        warnings.warn(
            f"derivation cache entry {str(path)!r} cannot be read ({exc.strerror}): recomputed",
            CacheWarning,
            stacklevel=3,
        )
        return None
    try:
        if len(raw) > _MAX_BYTES:
            raise _Rejected(f"it is larger than {_MAX_BYTES} bytes")
        body = _open(raw, key, name)
        # authenticated; still read only through the closed vocabulary
        try:
            data = json.loads(body, parse_constant=_no_constant)
            return _approximation(data, osc, f"cache entry {str(path)!r}")
        except Exception as exc:  # whatever a malformed entry raises: nothing was executed
            raise _Rejected(f"its content is invalid: {exc}") from None
    except _Rejected as exc:
        warnings.warn(
            f"derivation cache entry {str(path)!r} ignored: {exc}; the derivation is "
            "recomputed and the entry overwritten",
            CacheWarning,
            stacklevel=3,
        )
        return None


def cached_derivation(
    method: str,
    fn: Callable[..., Approximation],
    osc: Oscillator,
    *,
    use_cache: bool | None = None,
    **options: Any,
) -> Approximation:
    """``fn(osc, **options)``, from the cache when an authenticated, valid entry exists.

    The result is identical either way (same expressions and steps); a cache that cannot be
    read or written only costs time. An entry that is not trusted (module docstring) is
    reported with a :class:`CacheWarning` naming its file, and recomputed.
    """
    if use_cache is None:
        use_cache = os.environ.get("PERTURB_CACHE", "1") != "0"
    if not use_cache:
        return fn(osc, **options)
    try:
        key = _secret()
    except _NoKey as exc:
        reason = str(exc)
        if reason not in _WARNED:
            _WARNED.add(reason)
            warnings.warn(f"derivation cache not used: {reason}", CacheWarning, stacklevel=2)
        return fn(osc, **options)
    name = derivation_key(method, fn, osc, options)
    path = cache_dir() / f"{name}.json"
    approx = _read(path, name, key, osc)
    if approx is not None:
        return approx
    approx = fn(osc, **options)
    try:
        body = json.dumps(_entry(approx), sort_keys=True, separators=(",", ":"))
        # store only what reads back as the very same approximation
        if _approximation(json.loads(body), osc) != approx:
            return approx
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("wb", dir=path.parent, delete=False, suffix=".tmp") as fh:
            try:
                fh.write(_seal(key, name, body.encode()))
                fh.close()
                os.replace(fh.name, path)  # complete or absent
            except BaseException:
                fh.close()
                with contextlib.suppress(OSError):
                    os.unlink(fh.name)
                raise
    except (OSError, ValueError, TypeError, KeyError, RecursionError, UnsupportedExpression):
        # a read-only or full disk, or an expression outside the table, costs only time
        # (ParseError, an expression outside the vocabulary, is a ValueError)
        pass
    return approx
