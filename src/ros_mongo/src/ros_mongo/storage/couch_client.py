"""The one HTTP client of every CouchDB request (store, replication, changes follower, CLI; no ROS).

`CouchClient(url)` reaches one database (`http(s)://[user:pass@]host[:port][/prefix...]/dbname`,
the last path segment the database, "%2F" for a "/" inside its name; anything before it a reverse
proxy's path prefix) and its server's root (`server=True`). Credentials: the URL's userinfo
(`urls.split_credentials`: percent-decoded, up to the last '@', so any printable password works,
raw or percent-encoded) sent as HTTP Basic, never shown. TLS: `tls_ca_file` (a private CA
bundle), `tls_cert_file` + `tls_key_file` (a client certificate), `tls_verify=False` only for
testing.

Answers outside `ok` raise one error mapping, in the caller's error family (`ErrorFamily`; the
store's by default, the replication's for ros_mongo.fleet.replication):
- connection errors, timeouts, a truncated body, 429, 5xx but 501 -> `unavailable` (retry later);
- 401, 403, 500 `error_saving_ddoc` forbidden, 501, a TLS failure -> `refused` (operator must act);
- 413 -> BatchTooLarge (`document_too_large` names the document);
- anything else -> `base`, as "CouchDB <method> <path> answered <status>: <error>: <reason>".
Messages quote the redacted URL and the server's reason with the password scrubbed.
"""
from typing import Any, NamedTuple, Optional, Tuple
from urllib.parse import quote, unquote

import requests

from ros_mongo.errors import BatchTooLarge, StoreError, StoreRefused, StoreUnavailable
from ros_mongo.urls import check_url, redact_url, scrub, split_credentials

__all__ = ["CouchClient", "ErrorFamily", "STORE_ERRORS"]


class ErrorFamily(NamedTuple):
    """The error classes a client raises: anything else, retry later, the operator must act."""

    base: type
    unavailable: type
    refused: type


STORE_ERRORS = ErrorFamily(StoreError, StoreUnavailable, StoreRefused)
_TLS_MARKERS = ("CERTIFICATE_VERIFY_FAILED", "TLSV13_ALERT_CERTIFICATE_REQUIRED", "SSLV3_ALERT",
                "WRONG_VERSION_NUMBER", "certificate required", "certificate verify failed")


class CouchClient:
    """One database on a CouchDB-API server, over one requests.Session.

    Attributes: `server_url` (root, with any proxy prefix, no credentials), `name` (the database,
    decoded), `db_url`, `auth` ((user, password) or None), `shown` (the
    redacted URL), `timeout` (seconds per request)."""

    def __init__(self, url: str, *, timeout: float = 30.0, tls_ca_file: Optional[str] = None,
                 tls_cert_file: Optional[str] = None, tls_key_file: Optional[str] = None,
                 tls_verify: bool = True, errors: ErrorFamily = STORE_ERRORS):
        check_url(url)
        self.errors = errors
        if not url.lower().startswith(("http://", "https://")):
            raise errors.base(f"not a CouchDB URL (http:// or https://): {redact_url(url)!r}")
        self.full_url = url.rstrip("/")
        self.shown = redact_url(self.full_url)
        bare, self.auth = split_credentials(self.full_url)
        bare = bare.split("?", 1)[0].split("#", 1)[0]
        scheme, rest = bare.split("://", 1)
        host, _, path = rest.partition("/")
        segments = [s for s in path.split("/") if s]
        if not segments:
            raise errors.base(f"URL names no database: {self.shown!r}")
        self.name = unquote(segments[-1])
        prefix = "/".join(segments[:-1])
        self.server_url = f"{scheme.lower()}://{host}" + (f"/{prefix}" if prefix else "")
        self.db_url = f"{self.server_url}/{quote(self.name, safe='')}"
        self.timeout = float(timeout)
        self.tls = (tls_ca_file, tls_cert_file, tls_key_file, tls_verify)
        self.session = requests.Session()
        self.session.headers.update({"Accept": "application/json"})
        self.session.auth = self.auth
        self.session.verify = str(tls_ca_file) if tls_ca_file else bool(tls_verify)
        if tls_cert_file:
            self.session.cert = ((str(tls_cert_file), str(tls_key_file)) if tls_key_file
                                 else str(tls_cert_file))
        # the environment's proxy settings (http_proxy, no_proxy, ...) read once: requests
        # otherwise reads all of os.environ on every request (measured: a third of the CPU of
        # uploading a camera image); TLS and the account come from the options above, not from
        # REQUESTS_CA_BUNDLE or ~/.netrc
        self.session.proxies = requests.utils.get_environ_proxies(self.server_url)
        self.session.trust_env = False

    def sibling(self, name: str, *, errors: Optional[ErrorFamily] = None) -> "CouchClient":
        """A client of database `name` on the same server, with the same account and TLS."""
        client = type(self).__new__(type(self))
        client.__dict__.update(self.__dict__)
        client.errors = errors or self.errors
        client.name = name
        client.db_url = f"{self.server_url}/{quote(name, safe='')}"
        client.shown = redact_url(self.full_url.rsplit("/", 1)[0] + "/" + quote(name, safe=""))
        client.session = requests.Session()
        for key in ("headers", "auth", "verify", "cert", "proxies", "trust_env"):
            setattr(client.session, key, getattr(self.session, key))
        return client

    def request(self, method: str, path: str = "", *, ok: Tuple[int, ...] = (200, 201, 202),
                server: bool = False, **kwargs) -> requests.Response:
        """`method` on the database (the server root when `server`); errors per the module doc."""
        url = (self.server_url if server else self.db_url) + path
        where = f"{method} {path.split('?')[0] or '/'}"
        if server:
            where += " (server)"
        timeout = kwargs.pop("timeout", self.timeout)
        try:
            # verify given per request: requests lets REQUESTS_CA_BUNDLE override the session's
            response = self.session.request(method, url, timeout=timeout, verify=self.session.verify,
                                             **kwargs)
        except requests.exceptions.SSLError as err:  # (a ConnectionError subclass: first)
            raise self.errors.refused(f"TLS with CouchDB at {self.shown} failed (check tls_ca_file / "
                                      f"tls_cert_file): {_tls_reason(err)}") from err
        except (requests.ConnectionError, requests.Timeout, requests.exceptions.ChunkedEncodingError,
                requests.exceptions.ContentDecodingError) as err:
            raise self.errors.unavailable(f"CouchDB at {self.shown} is unreachable or cut the answer "
                                          f"short: {type(err).__name__}") from err
        except requests.RequestException as err:
            raise self.errors.base(f"CouchDB request {where} on {self.shown} failed: "
                                   f"{type(err).__name__}") from err
        if response.status_code in ok:
            return response
        raise self.error(response, where)

    def error(self, response: requests.Response, where: str) -> Exception:
        """The typed error of an answer outside `ok` (see the module doc)."""
        status = response.status_code
        error, reason = _reason(response)
        said = scrub(f"{status}: {error}: {reason}" if error else f"{status}: {reason}", self.full_url)
        if status in (401, 403) or (error == "error_saving_ddoc" and "forbidden" in reason):
            return self.errors.refused(f"CouchDB refused {where} on {self.shown} ({said})")
        if status == 413:
            return BatchTooLarge(f"CouchDB refused {where} on {self.shown} as too large ({said})",
                                 doc_id=reason if error == "document_too_large" else None)
        if status == 429 or (status >= 500 and status != 501):
            return self.errors.unavailable(f"CouchDB at {self.shown} is unavailable ({where}: {said})")
        if status == 501:
            return self.errors.refused(f"CouchDB at {self.shown} does not support {where} ({said})")
        return self.errors.base(f"CouchDB {where} on {self.shown} answered {said}")

    def json(self, method: str, path: str = "", **kwargs) -> Any:
        """The JSON body of a successful request (a body that is not JSON: `unavailable`)."""
        response = self.request(method, path, **kwargs)
        try:
            return response.json()
        except ValueError:
            raise self.errors.unavailable(f"CouchDB at {self.shown} answered {method} "
                                          f"{path.split('?')[0] or '/'} with {response.status_code} "
                                          f"and a body that is not JSON ({len(response.content)} "
                                          f"bytes)") from None

    def server_info(self) -> dict:
        return self.json("GET", "/", server=True)

    def is_apache_couchdb(self) -> bool:
        """Apache CouchDB says {"couchdb": "Welcome"} at its root; pouchdb-server does not."""
        return "couchdb" in self.server_info()

    def close(self) -> None:
        self.session.close()


def _tls_reason(err: Exception) -> str:
    """The OpenSSL reason of a TLS failure (e.g. CERTIFICATE_VERIFY_FAILED), without any URL."""
    text = str(err)
    for marker in _TLS_MARKERS:
        if marker in text:
            return marker
    return type(err).__name__


def _reason(response: requests.Response) -> Tuple[str, str]:
    """(error, reason) of a CouchDB error answer."""
    try:
        data = response.json()
        if isinstance(data, dict):
            return str(data.get("error", "")), str(data.get("reason", ""))
    except ValueError:
        pass
    return "", response.text[:300].strip()
