"""Mango selectors evaluated here, as Apache CouchDB 3 evaluates them (no ROS, no server).

Wherever ros_mongo matches documents itself (the changes follower, the messages inside a chunk) it
uses `matches(doc, selector)`: the answer Apache CouchDB's own `_find` gives for the same
selector (checked against the real server by test_mango.py). Its rules:
- Top-level fields and `$and` all hold; a field's value that is no operator object means `$eq`;
  `{"a": {"b": 1}}` is the field "a.b"; a path walks objects and, with a number, arrays.
- A missing field fails every condition on it (`$ne`, `$nin` and `$type` too) except a lone
  `{"$exists": false}`; a present null is a value: `$eq null` and `$exists true` match it. A
  path through a value that is no object ("a.b" where "a" is null or 5) fails every condition,
  `$exists: false` too.
- `$not` and `$nor` negate the conditions on the fields inside them, so a missing field fails
  them too (`{"$nor": [{"a": 1}]}` never matches a document without "a"); but a `$not` right
  inside `$elemMatch` / `$allMatch` is a plain "not" (`{"$not": {"b": 1}}` matches the element
  5), as measured on Apache CouchDB 3.5.
- Values compare by CouchDB's collation: null < false < true < numbers < strings < arrays <
  objects, so ranges cross types ("x" is `$gt` 1); 1 equals 1.0. Strings compare by code point
  here, by ICU collation there: the same for equality, not for ranges across letter case.
- No implicit array traversal: `$eq 1` never matches [1] (`$elemMatch`, `$all`, `$in` look inside).
  `$in` on an array: one element equals one argument; `$nin` on an array: not that.
  `$all`: every argument is an element, of the same JSON number kind (1 is not 1.0), or the
  one argument equals the array itself; `$size`;
  `$elemMatch` / `$allMatch` (an empty array matches no `$allMatch`); `$regex` (strings only,
  unanchored); `$type` (null, boolean, number, string, array, object); `$mod` [divisor, rest]
  (integers only).
An operator it does not know raises SelectorError (a QueryError) when the selector is compiled.
"""
import re
from typing import Any, Callable, Dict, List

from ros_mongo.errors import QueryError

__all__ = ["SelectorError", "compile_selector", "matches"]

_MISSING = object()  # a path's last key is not in its object: only `$exists: false` holds
_BAD_PATH = object()  # a path goes through a value that is no object (or past an array): nothing holds
Predicate = Callable[[Any], bool]


class SelectorError(QueryError):
    """A selector that is malformed or uses an operator this evaluator does not know."""


def matches(doc: Dict[str, Any], selector: Dict[str, Any]) -> bool:
    """Whether `doc` matches `selector` (compile once with `compile_selector` for many docs)."""
    return compile_selector(selector)(doc)


def compile_selector(selector: Dict[str, Any]) -> Predicate:
    """A function doc -> bool meaning what `selector` means to Apache CouchDB."""
    if not isinstance(selector, dict):
        raise SelectorError(f"a selector is a JSON object, got {selector!r:.80}")
    for key in selector:
        if key.startswith("$") and key not in ("$and", "$or", "$nor", "$not"):
            raise SelectorError(f"operator {key} needs a field")
    return _conjunction([_clause(key, value, ()) for key, value in selector.items()])


def _conjunction(preds: List[Predicate]) -> Predicate:
    return lambda doc: all(pred(doc) for pred in preds)


def _disjunction(preds: List[Predicate]) -> Predicate:
    return lambda doc: any(pred(doc) for pred in preds)


def _clause(key: str, value: Any, path: tuple, negated: bool = False,
            element: bool = False) -> Predicate:
    """One key of a selector object met at `path` (a field path or an operator); its negation
    when `negated`, pushed down to the fields as the server does (a missing field fails it), but
    for a `$not` inside `$elemMatch` / `$allMatch` (`element`): a plain "not" there."""
    if key == "$not" and element:
        inner = _object(value, path, element=True)
        return lambda doc: not inner(doc)
    if key in ("$and", "$or", "$nor"):
        inner_negated = negated != (key == "$nor")
        parts = [_object(item, path, inner_negated) for item in _selectors(key, value)]
        any_of = (key == "$or") != negated  # De Morgan
        return _disjunction(parts) if any_of else _conjunction(parts)
    if key == "$not":
        return _object(value, path, not negated)
    if key.startswith("$"):  # at path (): the value itself (an element, inside $elemMatch)
        return _field(path, _operator(key, value), negated)
    if _is_fields(value):
        return _object(value, path + tuple(_split_path(key)), negated, element)
    return _field(path + tuple(_split_path(key)), _operator("$eq", value), negated)


def _selectors(key: str, value: Any) -> list:
    if not isinstance(value, list):
        raise SelectorError(f"{key} takes a list of selectors, got {value!r:.80}")
    return value


def _is_fields(value: Any) -> bool:
    return isinstance(value, dict) and bool(value)


def _object(value: Any, path: tuple, negated: bool = False, element: bool = False) -> Predicate:
    if not isinstance(value, dict):
        raise SelectorError(f"expected a selector object, got {value!r:.80}")
    parts = [_clause(key, item, path, negated, element) for key, item in value.items()]
    return _disjunction(parts) if negated else _conjunction(parts)


def _split_path(key: str) -> List[str]:
    return [part.replace("\0", ".") for part in key.replace("\\.", "\0").split(".")]


def _field(path: tuple, test: Predicate, negated: bool) -> Predicate:
    lone_exists_false = getattr(test, "exists_false", False) and not negated

    def check(doc: Any) -> bool:
        value = _get(doc, path)
        if value is _MISSING:
            return lone_exists_false
        if value is _BAD_PATH:
            return False
        return test(value) != negated
    return check


def _get(value: Any, path: tuple) -> Any:
    for part in path:
        if isinstance(value, dict):
            value = value.get(part, _MISSING)
            if value is _MISSING:
                return value
        elif isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        else:
            return _BAD_PATH
    return value


def _operator(op: str, arg: Any) -> Predicate:
    """A test of a present value."""
    if op in _COMPARISONS:
        want = _COMPARISONS[op]
        return lambda value: want(collate(value, arg))
    if op in _BUILDERS:
        return _BUILDERS[op](arg)
    raise SelectorError(f"unknown selector operator {op}")


_COMPARISONS: Dict[str, Callable[[int], bool]] = {
    "$eq": lambda c: c == 0, "$ne": lambda c: c != 0, "$lt": lambda c: c < 0,
    "$lte": lambda c: c <= 0, "$gt": lambda c: c > 0, "$gte": lambda c: c >= 0}


def _in(args: Any) -> Predicate:
    if not isinstance(args, list):
        raise SelectorError(f"$in takes a list, got {args!r:.80}")

    def test(value: Any) -> bool:
        values = value if isinstance(value, list) else [value]
        return any(collate(v, a) == 0 for a in args for v in values)
    return test


def _nin(args: Any) -> Predicate:
    inside = _in(args)
    return lambda value: not inside(value)


def _exists(arg: Any) -> Predicate:
    def test(value: Any) -> bool:
        return bool(arg)
    test.exists_false = not arg  # type: ignore[attr-defined]
    return test


def _all(args: Any) -> Predicate:
    if not isinstance(args, list):
        raise SelectorError(f"$all takes a list, got {args!r:.80}")

    def test(value: Any) -> bool:
        if not isinstance(value, list):
            return False
        has = all(any(_identical(a, v) for v in value) for a in args)
        return has or (len(args) == 1 and collate(args[0], value) == 0)
    return test


def _size(arg: Any) -> Predicate:
    return lambda value: isinstance(value, list) and not isinstance(arg, bool) and len(value) == arg


def _elem_match(arg: Any) -> Predicate:
    inner = _object(arg, (), element=True)
    return lambda value: isinstance(value, list) and any(inner(v) for v in value)


def _all_match(arg: Any) -> Predicate:
    inner = _object(arg, (), element=True)
    return lambda value: isinstance(value, list) and bool(value) and all(inner(v) for v in value)


def _regex(arg: Any) -> Predicate:
    try:
        pattern = re.compile(arg)
    except (re.error, TypeError) as err:
        raise SelectorError(f"$regex {arg!r:.80}: {err}") from None
    return lambda value: isinstance(value, str) and pattern.search(value) is not None


def _type(arg: Any) -> Predicate:
    if arg not in _TYPE_RANK:
        raise SelectorError(f"$type takes one of {sorted(_TYPE_RANK)}, got {arg!r:.80}")
    return lambda value: _type_name(value) == arg


def _mod(arg: Any) -> Predicate:
    if not (isinstance(arg, list) and len(arg) == 2 and all(_is_int(a) for a in arg) and arg[0]):
        raise SelectorError(f"$mod takes [divisor, remainder] (integers), got {arg!r:.80}")
    divisor, rest = arg
    # Erlang's rem: the sign of the dividend
    return lambda value: _is_int(value) and int(abs(value) % abs(divisor)) * (-1 if value < 0 else 1) == rest


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


_BUILDERS: Dict[str, Callable[[Any], Predicate]] = {
    "$in": _in, "$nin": _nin, "$exists": _exists, "$all": _all, "$size": _size,
    "$elemMatch": _elem_match, "$allMatch": _all_match, "$regex": _regex, "$type": _type,
    "$mod": _mod}
_TYPE_RANK = {"null": 0, "boolean": 1, "number": 3, "string": 4, "array": 5, "object": 6}


def _type_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, (int, float)):
        return "number"
    if isinstance(value, str):
        return "string"
    return "array" if isinstance(value, list) else "object"


def _rank(value: Any) -> int:
    if isinstance(value, bool):
        return 2 if value else 1
    return _TYPE_RANK[_type_name(value)]


def _identical(a: Any, b: Any) -> bool:
    """Erlang term equality of decoded JSON (1 and 1.0 differ; $all compares so)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, list):
        return len(a) == len(b) and all(_identical(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return list(a) == list(b) and all(_identical(a[k], b[k]) for k in a)
    return a == b


def collate(a: Any, b: Any) -> int:
    """-1, 0 or 1: CouchDB's collation of two JSON values (strings by code point, see above)."""
    rank_a, rank_b = _rank(a), _rank(b)
    if rank_a != rank_b:
        return -1 if rank_a < rank_b else 1
    if isinstance(a, list):
        for x, y in zip(a, b):
            order = collate(x, y)
            if order:
                return order
        return (len(a) > len(b)) - (len(a) < len(b))
    if isinstance(a, dict):
        for (key_a, x), (key_b, y) in zip(a.items(), b.items()):
            order = collate(key_a, key_b) or collate(x, y)
            if order:
                return order
        return (len(a) > len(b)) - (len(a) < len(b))
    if a is None or isinstance(a, bool):
        return 0
    return (a > b) - (a < b)
