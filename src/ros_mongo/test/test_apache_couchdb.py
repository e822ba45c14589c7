"""What only a real Apache CouchDB 3 answers, checked on the real server (ros_harness
`apache_couchdb`: a real node, its admin and a database member; skipped where ../shared/couchdb is
absent): a wrong password and no credentials, a document over `max_document_size` refusing its
whole `_bulk_docs` request (the store splits it out), and a `_find` sort no index covers. The
store talks as the member."""
import uuid

import pytest
import requests
from std_msgs.msg import String

from ros_mongo import TopicInfo, make_record, open_store
from ros_mongo.errors import DocumentsRejected, QueryError, StoreRefused
from ros_mongo.records import split_time

pytestmark = pytest.mark.db


def _records(texts, t0=1000.0):
    from ros_mongo_samples import serialized

    return [make_record("/notes", String, serialized(String(data=text)), receive=split_time(t0 + 0.01 * i),
                        session_id="s1") for i, text in enumerate(texts)]


def _stored_ids(admin_url):
    rows = requests.get(f"{admin_url}/_all_docs", timeout=30).json()["rows"]
    return [row["id"] for row in rows if row["id"][0].isdigit()]


def test_a_wrong_password_and_no_credentials_are_refused_with_the_servers_reason(apache_couchdb,
                                                                                  apache_couchdb_url):
    user, password = apache_couchdb.member
    wrong = apache_couchdb_url.replace(f"{user}:{password}@", f"{user}:Not-{password}@")
    with pytest.raises(StoreRefused) as refused:
        open_store(wrong)
    assert "Name or password is incorrect." in str(refused.value) and password not in str(refused.value)
    with pytest.raises(StoreRefused) as refused:
        open_store(apache_couchdb_url.replace(f"{user}:{password}@", ""))
    assert "You are not authorized to access this db." in str(refused.value)


def test_one_document_over_the_size_limit_is_split_out_named_and_the_rest_stored(apache_couchdb):
    """The server refuses the whole `_bulk_docs` request (413 document_too_large naming one
    document); the store splits the batch until that document is alone and stores the rest."""
    name = "test_size_" + uuid.uuid4().hex[:8]
    url = apache_couchdb.database_url(name)
    records = _records(["small"] * 5 + ["x" * 60000] + ["small"] * 5)
    old = apache_couchdb.set_config("couchdb", "max_document_size", "20000")
    try:
        with open_store(url) as store:
            store.put_topic(TopicInfo.of_class("/notes", String))
            with pytest.raises(DocumentsRejected) as refused:
                store.insert_records(records)
            assert "document_too_large" in str(refused.value)
            assert refused.value.rejected_ids == frozenset([records[5].id])  # the server named the document
            assert store.insert_records(records[:5] + records[6:]) == 0  # the rest was stored
    finally:
        apache_couchdb.set_config("couchdb", "max_document_size", old)
    assert sorted(_stored_ids(apache_couchdb.admin_database_url(name))) == sorted(
        r.id for r in records[:5] + records[6:])


def test_a_sort_no_index_covers_is_a_query_error_and_member_reads_need_none(apache_couchdb_url):
    with open_store(apache_couchdb_url) as store:
        assert store.indexed is False                      # a member may not create the indexes
        store.put_topic(TopicInfo.of_class("/notes", String))
        store.insert_records(_records([f"m{i}" for i in range(30)]))
        with pytest.raises(QueryError, match="no_usable_index"):
            store._find({"selector": {"kind": "message"}, "sort": [{"receive_time": "asc"}]})
        newest = [m.message().data for m in store.find_messages(newest_first=True, limit=3)]
        window = [m.message().data for m in store.find_messages(start_time=1000.1, end_time=1000.13)]
    assert newest == ["m29", "m28", "m27"] and window == ["m10", "m11", "m12", "m13"]
