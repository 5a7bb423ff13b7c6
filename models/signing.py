"""Keyed signatures of world-model files: HMAC-SHA256 with a key the user holds.

The SHA-256 checksum of a model file (:mod:`models.io`) detects accidents: a truncated copy,
a flipped byte, an edited value. It is not a secret: anyone who changes a file can compute
the checksum again, and the file loads. A signature is what tells a file you wrote from one
someone else changed: ``HMAC-SHA256(key, checksum)``, stored next to the checksum when a key
is given on save, and required and checked when a key is given on load.

The key is an argument (``key=``, bytes or str) or, when that is None, the environment
variable :data:`KEY_ENV` (``PAL_MODEL_KEY``). Keep it out of the files you share: whoever
holds the key can sign.
"""

from __future__ import annotations

import hashlib
import hmac
import os

__all__ = ["KEY_ENV", "problem", "resolve_key", "sign"]

#: Environment variable read for the signing key when no ``key=`` is passed.
KEY_ENV = "PAL_MODEL_KEY"
_CONTEXT = b"pal.world_model signature\0"


def resolve_key(key: bytes | str | None) -> bytes | None:
    """The signing key: ``key`` (str as UTF-8), else ``$PAL_MODEL_KEY``, else None (no signing).

    Raises:
        ValueError: ``key`` is empty or neither bytes nor str.
    """
    if key is None:
        env = os.environ.get(KEY_ENV)
        return env.encode("utf-8") if env else None
    if isinstance(key, str):
        key = key.encode("utf-8")
    if not isinstance(key, bytes) or not key:
        raise ValueError(f"key must be non-empty bytes or str, got {type(key).__name__} {key!r:.20}")
    return key


def sign(key: bytes, checksum: str) -> str:
    """Hex ``HMAC-SHA256(key, checksum)`` of a file's content checksum."""
    return hmac.new(key, _CONTEXT + checksum.encode("ascii"), hashlib.sha256).hexdigest()


def problem(key: bytes, checksum: str, signature: object) -> str | None:
    """What is wrong with ``signature`` under ``key`` (None when it is valid)."""
    if signature is None:
        return (
            f"is not signed, but a key was given (key= or ${KEY_ENV}); refusing an unsigned file "
            "(save it with the key to sign it)"
        )
    if not isinstance(signature, str) or not hmac.compare_digest(signature, sign(key, checksum)):
        return "has a signature that does not match the key: it was changed after signing or signed with another key"
    return None
