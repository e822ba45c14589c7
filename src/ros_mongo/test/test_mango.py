"""The selector evaluator (ros_mongo.storage.mango) answers as Apache CouchDB does: the same selectors run
on the real server (`_find`, ros_harness `apache_couchdb`; skipped where ../shared/couchdb is
absent) and on the evaluator must select the same documents. The expected sets are the server's
answers, never the evaluator's; the unit test below has them worked out by hand."""
import uuid

import pytest
import requests

from ros_mongo.storage.mango import SelectorError, compile_selector, matches

# Documents with every shape a selector treats differently: missing and null fields, numbers
# written as integers and floats, booleans, strings, arrays (empty, mixed, of objects), objects.
DOCS = [
    {"_id": "d01", "a": 1, "s": "alpha", "arr": [1, 2, 3], "o": {"p": 1, "q": {"r": "x"}}},
    {"_id": "d02", "a": 2.0, "s": "beta", "arr": [], "o": {"p": 2}},
    {"_id": "d03", "a": None, "s": None, "arr": [None, 1], "o": None},
    {"_id": "d04", "s": "gamma", "arr": ["x", 5, True], "o": {}},
    {"_id": "d05", "a": "1", "s": "alphabet", "arr": [{"b": 1}, {"b": 2}], "o": {"p": None}},
    {"_id": "d06", "a": True, "arr": [[1, 2], 3], "o": {"q": {"r": "y"}}},
    {"_id": "d07", "a": False, "s": "", "arr": 7, "o": [1, 2]},
    {"_id": "d08", "a": [1, 2], "s": "delta", "arr": [1.0, 2.0]},
    {"_id": "d09", "a": -3, "s": "zeta", "arr": ["alpha", "beta"], "o": {"p": 3, "q": {"r": None}}},
    {"_id": "d10", "a": 1.5, "s": "eta", "arr": [2, 3, 4, 5], "o": {"p": [1, 2]}},
    {"_id": "d11"},
]

SELECTORS = [
    {"a": 1}, {"a": {"$eq": 1.0}}, {"a": None}, {"a": {"$eq": None}}, {"a": {"$ne": None}},
    {"a": {"$ne": 1}}, {"a": {"$gt": 1}}, {"a": {"$gte": 1, "$lt": 2}}, {"a": {"$lt": "0"}},
    {"a": {"$exists": True}}, {"a": {"$exists": False}}, {"s": {"$exists": False}},
    {"a": {"$in": [1, "1", None]}}, {"a": {"$nin": [1, 2]}}, {"a": {"$nin": [None]}},
    {"arr": {"$in": [2]}}, {"arr": {"$nin": [1]}}, {"arr": 1}, {"arr": [1, 2, 3]},
    {"arr": {"$all": [1, 2]}}, {"arr": {"$all": [2.0]}}, {"arr": {"$all": [[1, 2]]}},
    {"arr": {"$size": 2}}, {"arr": {"$size": 0}}, {"arr": {"$elemMatch": {"$gt": 3}}},
    {"arr": {"$elemMatch": {"b": 2}}}, {"arr": {"$elemMatch": {"$eq": None}}},
    {"arr": {"$allMatch": {"$gt": 0}}}, {"arr.0": 1}, {"arr.1.b": 2},
    {"s": {"$regex": "^alpha"}}, {"s": {"$regex": "a$"}}, {"a": {"$regex": "1"}},
    {"o.p": 1}, {"o": {"p": {"$gte": 2}}}, {"o.q.r": {"$exists": True}}, {"o.q.r": None},
    {"o.p": {"$ne": 1}}, {"o": {"$type": "object"}}, {"a": {"$type": "number"}},
    {"a": {"$type": "null"}}, {"o": {"$size": 2}}, {"o": {}},
    {"$or": [{"a": 1}, {"s": "beta"}]}, {"$nor": [{"a": 1}]}, {"$not": {"a": 1}},
    {"a": {"$not": {"$eq": 1}}}, {"$and": [{"a": {"$gt": 0}}, {"s": {"$gt": "b"}}]},
    {"a": {"$mod": [2, 1]}}, {"a": {"$exists": False, "$ne": 3}},
    {"$or": [{"a": {"$exists": False}}, {"$nor": [{"a": {"$eq": 1}}]}]},
    {"$not": {"$or": [{"a": 1}, {"s": "beta"}]}}, {"$nor": [{"a": 1}, {"s": "beta"}]},
    {"$not": {"a": {"$exists": False}}}, {"$nor": [{"o.p": {"$gt": 1}}, {"a": {"$exists": True}}]},
    {"arr": {"$elemMatch": {"$not": {"b": 1}}}}, {"$not": {"$and": [{"a": 1}, {"s": "alpha"}]}},
    {"arr": {"$elemMatch": {"$nor": [{"b": 1}, {"b": 2}]}}}, {"arr": {"$allMatch": {"$not": {"$eq": None}}}},
    {"$nor": [{"$not": {"a": 1}}]}, {"o.p": {"$exists": False}}, {"o.p.x": {"$exists": False}},
    {"arr.9": {"$exists": False}}, {"$nor": [{"o.p": 1}]},
    {"$and": [{"s": {"$exists": True}}, {"$not": {"s": {"$regex": "^a"}}}]},
]


def test_the_evaluator_answers_as_worked_out_by_hand():
    doc = {"a": 1, "n": None, "arr": [1, {"b": 2}], "s": "xy"}
    assert matches(doc, {"n": None}) and matches(doc, {"n": {"$exists": True}})  # a present null
    assert not matches(doc, {"m": None}) and not matches(doc, {"m": {"$ne": 1}})  # missing fails
    assert matches(doc, {"m": {"$exists": False}}) and not matches(doc, {"$not": {"m": 1}})
    assert not matches(doc, {"arr": 1}) and matches(doc, {"arr": {"$in": [1]}})  # no traversal
    assert matches(doc, {"arr.1.b": 2}) and matches(doc, {"arr": {"$elemMatch": {"b": 2}}})
    assert matches(doc, {"s": {"$gt": 5}}) and matches(doc, {"a": {"$eq": 1.0}})  # collation
    with pytest.raises(SelectorError, match=r"\$where"):
        compile_selector({"a": {"$where": 1}})


@pytest.mark.db
def test_the_evaluator_selects_what_apache_couchdb_selects(apache_couchdb):
    name = "mango_" + uuid.uuid4().hex[:10]
    apache_couchdb.create_database(name)
    url = f"{apache_couchdb.url}/{name}"
    assert requests.post(f"{url}/_bulk_docs", json={"docs": DOCS}, timeout=60).status_code == 201
    disagreements = []
    for selector in SELECTORS:
        answer = requests.post(f"{url}/_find", json={"selector": selector, "limit": 1000}, timeout=60)
        assert answer.status_code == 200, (selector, answer.text)
        server = sorted(doc["_id"] for doc in answer.json()["docs"])
        check = compile_selector(selector)
        here = sorted(doc["_id"] for doc in DOCS if check(doc))
        if server != here:
            disagreements.append((selector, server, here))
    assert disagreements == [], "\n".join(map(str, disagreements))
