"""The teacher password: stored only as a salted scrypt hash; checked in constant time.

The password comes from the environment (``ASSEMBLY_AGENT_TEACHER_PASSWORD``) or is set once by the
first teacher (``POST /api/auth/setup``). A successful login returns a random session token (also set
as the ``teacher_token`` cookie); editing endpoints accept that token or the password itself in the
``X-Teacher-Password`` header.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time

from app.storage import Storage, StorageError

_SCRYPT = {"n": 2**14, "r": 8, "p": 1, "dklen": 32}
SECRET_KEY = "teacher_password"
TOKEN_TTL_S = 12 * 3600.0
MIN_PASSWORD_LENGTH = 10
MAX_PASSWORD_LENGTH = 1024


def password_problem(password: str) -> str | None:
    """Why ``password`` is too weak to become the teacher password, or ``None`` when it will do."""
    if len(password) < MIN_PASSWORD_LENGTH:
        return f"use at least {MIN_PASSWORD_LENGTH} characters"
    if len(password) > MAX_PASSWORD_LENGTH:
        return f"use at most {MAX_PASSWORD_LENGTH} characters"
    if len(set(password)) < 4:
        return "use at least 4 different characters"
    return None


def hash_password(password: str, salt: bytes | None = None) -> str:
    """``scrypt$n$r$p$salt_hex$hash_hex`` for ``password`` (a fresh 16-byte salt when none is given)."""
    salt = secrets.token_bytes(16) if salt is None else salt
    digest = hashlib.scrypt(password.encode("utf-8"), salt=salt, **_SCRYPT)
    return f"scrypt${_SCRYPT['n']}${_SCRYPT['r']}${_SCRYPT['p']}${salt.hex()}${digest.hex()}"


def verify_password(password: str, stored: str) -> bool:
    """Whether ``password`` matches a :func:`hash_password` string."""
    try:
        scheme, n, r, p, salt_hex, hash_hex = stored.split("$")
        if scheme != "scrypt":
            return False
        digest = hashlib.scrypt(
            password.encode("utf-8"),
            salt=bytes.fromhex(salt_hex),
            n=int(n),
            r=int(r),
            p=int(p),
            dklen=len(hash_hex) // 2,
        )
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(digest.hex(), hash_hex)


class TeacherAuth:
    """Password hash in :class:`Storage`, session tokens in memory."""

    def __init__(self, storage: Storage, env_password: str | None = None) -> None:
        self.storage = storage
        self._tokens: dict[str, float] = {}
        self._lock = threading.Lock()
        self._memory_hash: str | None = None  # the environment's password when the database is read-only
        if env_password:
            problem = password_problem(env_password)
            if problem is not None:
                raise ValueError(f"the teacher password from ASSEMBLY_AGENT_TEACHER_PASSWORD is too weak: {problem}")
            try:
                stored = storage.get_secret(SECRET_KEY)
            except StorageError:
                stored = None
            if stored is None or not verify_password(env_password, stored):
                hashed = hash_password(env_password)
                try:
                    storage.set_secret(SECRET_KEY, hashed)
                except StorageError:  # a read-only database: the password holds for this run
                    self._memory_hash = hashed

    def _stored_hash(self) -> str | None:
        return self._memory_hash or self.storage.get_secret(SECRET_KEY)

    @property
    def is_configured(self) -> bool:
        return self._stored_hash() is not None

    def setup(self, password: str) -> None:
        """Set the first password; refused once one exists."""
        problem = password_problem(password)
        if problem is not None:
            raise ValueError(f"password: {problem}")
        with self._lock:
            if self.is_configured:
                raise PermissionError("a teacher password is already set")
            self.storage.set_secret(SECRET_KEY, hash_password(password))

    def check_password(self, password: str | None) -> bool:
        stored = self._stored_hash()
        return bool(password) and stored is not None and verify_password(password, stored)

    def login(self, password: str) -> str | None:
        """A new session token, or ``None`` for a wrong password."""
        if not self.check_password(password):
            return None
        return self.new_token()

    def new_token(self) -> str:
        """A fresh session token (for a teacher whose password was just checked)."""
        token = secrets.token_urlsafe(32)
        with self._lock:
            now = time.time()
            for stale in [t for t, expiry in self._tokens.items() if expiry < now]:
                del self._tokens[stale]
            self._tokens[token] = now + TOKEN_TTL_S
        return token

    def check_token(self, token: str | None) -> bool:
        if not token:
            return False
        with self._lock:
            expiry = self._tokens.get(token)
            if expiry is None:
                return False
            if expiry < time.time():
                del self._tokens[token]
                return False
        return True

    def logout(self, token: str | None) -> None:
        with self._lock:
            self._tokens.pop(token or "", None)
