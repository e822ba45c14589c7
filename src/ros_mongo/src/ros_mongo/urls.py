"""Database URLs: redaction for anything shown to people, and credentials kept out of them.

Contracts:
- `redact_url(url)` never returns a password or a query-string secret: the userinfo's password
  becomes `***` (the user name stays), the values of secret-looking query options (password=,
  token=, secret=, key=, authMechanismProperties=, ...) become `***` (authSource, authMechanism,
  replicaSet, w, journal ... stay). It never raises: multi-host MongoDB URLs
  (mongodb://u:p@h1:27017,h2:27017/db?replicaSet=rs), URLs without `://` and non-strings are
  redacted too.
- `with_credentials(url, credentials_file=..., environ=...)` is the URL to connect with: the
  password (and optionally the user) from the environment variables ROS_MONGO_DB_PASSWORD /
  ROS_MONGO_DB_USER, or from a credentials file, put into a password-free `url`. The file holds one
  line, `user:password` or `password` (the user then comes from the URL or ROS_MONGO_DB_USER);
  surrounding whitespace is ignored, `:` in the password is allowed after the first one. A
  password in the URL itself wins over both (and is what `password_in_url` reports, so callers
  can warn that it shows in `ps` and parameter listings).
- `check_url(url)` raises StoreError for a URL without a scheme, quoting only its redacted form.
- `split_credentials(url)` is the one URL/credential parser of the HTTP clients: the URL without
  its userinfo and the percent-decoded (user, password), the userinfo ending at the LAST '@'
  before the path (a password may hold '@', '/' and ':' raw or percent-encoded).
- `scrub(text, url)` removes the URL's password (raw and percent-encoded) from any text, for
  error messages built from driver exceptions.
- `with_credentials` is the one place every node's database URL goes through (`open_store` calls
  it, and so do the fleet feeds of the central database): when the URL it is given carries a
  password, it warns once per process and URL (`warn_password_in_url`) that roslaunch prints
  parameters (the first characters of `db_url`, password included, in its start-up summary) and
  names the credentials-file parameters instead. The warning quotes the redacted URL only. It is
  logged on `rosout.ros_mongo`, the logger `rospy.logwarn(..., logger_name="ros_mongo")` uses, so
  in any rospy node it reaches /rosout, the screen and the node's log file whichever package
  loggers that node routes; outside ROS it goes to stderr.
"""
import hashlib
import logging
import os
import re
import threading
from pathlib import Path
from typing import Mapping, Optional, Set, Tuple
from urllib.parse import quote, unquote

from ros_mongo.errors import StoreError

__all__ = ["redact_url", "with_credentials", "check_url", "scrub", "split_credentials", "password_in_url",
           "password_warning", "warn_password_in_url", "PASSWORD_ENV", "USER_ENV", "CredentialsError",
           "NODE_CREDENTIALS_HINT"]

PASSWORD_ENV = "ROS_MONGO_DB_PASSWORD"
USER_ENV = "ROS_MONGO_DB_USER"
_MASK = "***"
# query options whose values are secrets (matched case-insensitively, as substrings)
_SECRET_KEYS = ("pass", "pwd", "secret", "token", "key", "credential", "signature", "sig",
                "authmechanismproperties", "session")
_PUBLIC_KEYS = ("authsource", "authmechanism", "replicaset", "tlscafile", "tlscertificatekeyfile")

#: Where a node takes the password instead of the URL.
NODE_CREDENTIALS_HINT = (f"in a file named by the node's ~db_credentials_file parameter "
                         f"(~central_credentials_file for ~central_url; one line 'user:password' or "
                         f"'password') or in ${PASSWORD_ENV}")
_WARNING_LOG = logging.getLogger("rosout.ros_mongo")
_warned: Set[str] = set()  # sha256 of each URL warned about in this process
_warned_lock = threading.Lock()


class CredentialsError(StoreError):
    """The credentials file or variables cannot be used (the message never holds the secret)."""


def _split(url: str) -> Tuple[str, str, str, str]:
    """(scheme + '://' or '', userinfo or '', hosts + path, query + fragment incl. '?'/'#')."""
    scheme = ""
    rest = url
    if "://" in url:
        scheme, rest = url.split("://", 1)
        scheme += "://"
    cut = len(rest)
    for mark in "?#":
        at = rest.find(mark)
        if at != -1:
            cut = min(cut, at)
    location, tail = rest[:cut], rest[cut:]
    # the userinfo ends at the LAST '@' before the path (a password may hold '@' unescaped)
    slash = location.find("/", location.rfind("@") + 1 if "@" in location else 0)
    authority = location if slash == -1 else location[:slash]
    path = "" if slash == -1 else location[slash:]
    userinfo = ""
    if "@" in authority:
        userinfo, authority = authority.rsplit("@", 1)
        userinfo += "@"
    return scheme, userinfo, authority + path, tail


def _redact_userinfo(userinfo: str) -> str:
    if not userinfo:
        return ""
    user = userinfo[:-1]
    if ":" in user:
        return user.split(":", 1)[0] + ":" + _MASK + "@"
    return user + "@"  # a user name alone is no secret


def _secret_key(key: str) -> bool:
    lowered = key.lower()
    if lowered in _PUBLIC_KEYS:
        return False
    return any(word in lowered for word in _SECRET_KEYS)


def _redact_tail(tail: str) -> str:
    if not tail.startswith("?"):
        return tail
    query, hash_mark, fragment = tail[1:].partition("#")
    parts = []
    for item in re.split(r"([&;])", query):
        if item in ("&", ";") or "=" not in item:
            parts.append(item)
            continue
        key, _value = item.split("=", 1)
        parts.append(f"{key}={_MASK}" if _secret_key(unquote(key)) else item)
    return "?" + "".join(parts) + hash_mark + fragment


def redact_url(url) -> str:
    """`url` without its password and query-string secrets (for logs, errors, diagnostics)."""
    if not isinstance(url, str):
        return f"<{type(url).__name__}>"
    scheme, userinfo, location, tail = _split(url)
    return scheme + _redact_userinfo(userinfo) + location + _redact_tail(tail)


def password_in_url(url: str) -> bool:
    """True if `url` carries a password in its userinfo or a secret query option."""
    if not isinstance(url, str):
        return False
    return redact_url(url) != url


def password_warning(url, *, hint: str = NODE_CREDENTIALS_HINT) -> Optional[str]:
    """The warning for a `url` that carries a password, the first time this process sees that
    URL (None otherwise). It quotes the redacted URL only."""
    if not password_in_url(url):
        return None
    key = hashlib.sha256(url.encode("utf-8", "replace")).hexdigest()
    with _warned_lock:
        if key in _warned:
            return None
        _warned.add(key)
    return (f"the database URL {redact_url(url)} carries a password, and roslaunch prints parameters "
            f"when it starts (the first characters of every value, so of the password too), as do "
            f"`rosparam get` and `ps` for command-line URLs: keep the URL password-free and put the "
            f"password {hint}")


def warn_password_in_url(url, *, hint: str = NODE_CREDENTIALS_HINT) -> bool:
    """Log `password_warning(url)` as a WARNING (once per process and URL); True if it warned."""
    text = password_warning(url, hint=hint)
    if text is not None:
        _WARNING_LOG.warning(text)
    return text is not None


def check_url(url) -> None:
    """StoreError (quoting the redacted URL only) unless `url` is a string with a scheme."""
    if not isinstance(url, str) or "://" not in url:
        shown = redact_url(url) if isinstance(url, str) else repr(url)
        raise StoreError(f"database URL must look like http://host:5984/db or mongodb://host:27017/db, "
                         f"got {shown!r}")


def read_credentials_file(path: str) -> Tuple[Optional[str], str]:
    """(user or None, password) from a credentials file (CredentialsError naming the path)."""
    try:
        text = Path(os.path.expanduser(path)).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        reason = getattr(err, "strerror", None) or "unreadable"
        raise CredentialsError(f"cannot read the database credentials file {path}: "
                               f"{type(err).__name__}: {reason}") from None
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.strip().startswith("#")]
    if len(lines) != 1:
        raise CredentialsError(f"the database credentials file {path} must hold one line, 'user:password' "
                               f"or 'password' (it holds {len(lines)} non-empty lines)")
    line = lines[0]
    if ":" in line:
        user, password = line.split(":", 1)
        return (user or None), password
    return None, line


def with_credentials(url: str, *, credentials_file: Optional[str] = None,
                     environ: Optional[Mapping[str, str]] = None, warn: bool = True) -> str:
    """The URL to connect with: `url` plus the user and password from the credentials file or the
    environment (ROS_MONGO_DB_USER / ROS_MONGO_DB_PASSWORD), unless `url` has a password already.
    The credentials file wins over the environment. A password in `url` itself is warned about
    once (`warn_password_in_url`) unless `warn` is False (a URL this process completed itself)."""
    check_url(url)
    if warn:
        warn_password_in_url(url)
    environ = os.environ if environ is None else environ
    scheme, userinfo, location, tail = _split(url)
    if ":" in userinfo:
        return url  # the URL has its password already
    user: Optional[str] = unquote(userinfo[:-1]) if userinfo else None
    password: Optional[str] = None
    if credentials_file:
        file_user, password = read_credentials_file(credentials_file)
        user = file_user or user
    elif environ.get(PASSWORD_ENV):
        password = environ[PASSWORD_ENV]
    if password is None:
        return url
    user = user or environ.get(USER_ENV)
    if not user:
        raise CredentialsError(f"a database password is given but no user: put the user in the URL "
                               f"({redact_url(url)}), the credentials file ('user:password') or {USER_ENV}")
    return f"{scheme}{quote(user, safe='')}:{quote(password, safe='')}@{location}{tail}"


def split_credentials(url: str) -> Tuple[str, Optional[Tuple[str, str]]]:
    """(`url` without its userinfo, (user, password) percent-decoded, or None without userinfo).
    The userinfo ends at the last '@' before the path; the user at its first ':'."""
    scheme, userinfo, location, tail = _split(url)
    if not userinfo:
        return url, None
    user, _, password = userinfo[:-1].partition(":")
    return scheme + location + tail, (unquote(user), unquote(password))


def scrub(text: str, url: str) -> str:
    """`text` with the password of `url` (raw and percent-encoded) and any URL in it redacted."""
    if not isinstance(url, str):
        return text
    _scheme, userinfo, _location, _tail = _split(url)
    if ":" in userinfo:
        password = userinfo[:-1].split(":", 1)[1]
        for secret in {password, unquote(password), quote(unquote(password), safe='')}:
            if len(secret) >= 1:
                text = text.replace(secret, _MASK)
    return re.sub(r"[A-Za-z][A-Za-z0-9+.-]*://[^\s'\"]+", lambda m: redact_url(m.group(0)), text)
