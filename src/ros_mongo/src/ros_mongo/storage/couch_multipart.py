"""A CouchDB document with attachments as one request body (no I/O): binary in a
`multipart/related` body, or base64 inside its JSON for `_bulk_docs`.

`PUT /db/<id>?new_edits=false` with this body stores the document and its attachments in one
request, the bytes as they are (inline attachments in JSON are base64: a third more bytes, and
encoding work on the sender). The first part is the document's JSON with an `_attachments` stub
per attachment (`follows: true` and its length), in the order of the parts after it; each
attachment's part names it (`Content-Disposition` filename: pouchdb-server matches parts by that
name, Apache CouchDB by order; both were checked). The boundary is random (128 bits) per body.
`inline_document` is the same document for `_bulk_docs` (CouchDB's fallback, see storage.couch).
"""
import secrets
from typing import Sequence, Tuple

import pybase64

__all__ = ["multipart_document", "inline_document", "ATTACHMENT_TYPE"]

#: The content type every attachment is stored with (as inline attachments were).
ATTACHMENT_TYPE = "application/octet-stream"
_TYPE = ATTACHMENT_TYPE.encode("ascii")


def multipart_document(body: bytes, rev: str,
                       attachments: Sequence[Tuple[str, bytes]]) -> Tuple[str, Tuple[bytes, ...]]:
    """(Content-Type header, body parts to join) for the document JSON `body` (an object, without
    `_rev` and `_attachments`) stored with revision `rev` and `attachments` ((name, bytes) each;
    names are plain attachment names: letters, digits, `_`)."""
    boundary = secrets.token_hex(16).encode("ascii")
    stubs = b",".join(b'"%s":{"content_type":"%s","follows":true,"length":%d}'
                      % (name.encode("ascii"), _TYPE, len(data))
                      for name, data in attachments)
    inner = body[1:-1]
    parts = [b"--", boundary, b"\r\nContent-Type: application/json\r\n\r\n{\"_rev\":\"",
             rev.encode("ascii"), b"\",", inner, b"," if inner else b"", b"\"_attachments\":{", stubs, b"}}"]
    for name, data in attachments:
        head = (b'\r\nContent-Disposition: attachment; filename="%s"\r\nContent-Type: %s\r\n'
                b"Content-Length: %d\r\n\r\n") % (name.encode("ascii"), _TYPE, len(data))
        parts += [b"\r\n--", boundary, head, data]
    parts += [b"\r\n--", boundary, b"--"]
    return f'multipart/related; boundary="{boundary.decode("ascii")}"', tuple(parts)


def inline_document(body: bytes, rev: str, attachments: Sequence[Tuple[str, bytes]]) -> Tuple[bytes, ...]:
    """The same document as `multipart_document`, its attachments base64 inside its JSON (parts to
    join; for `_bulk_docs` with `new_edits: false`). SIMD base64: a tenth of binascii's CPU."""
    inner = body[1:-1]
    parts = [b'{"_rev":"', rev.encode("ascii"), b'",', inner, b"," if inner else b"", b'"_attachments":{']
    for index, (name, data) in enumerate(attachments):
        head = b'"%s":{"content_type":"%s","data":"' % (name.encode("ascii"), _TYPE)
        parts += [b"," if index else b"", head, pybase64.b64encode(data), b'"}']
    return tuple(parts) + (b"}}",)
