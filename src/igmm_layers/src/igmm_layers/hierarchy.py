"""Class hierarchies: a query for a group ("furniture") covers its classes (chair, table, ...)."""
from typing import Dict, Iterable, List, Mapping, Sequence, Set

from igmm_layers.errors import InvalidInputError, UnknownNameError

__all__ = ["ANY", "ClassHierarchy"]

ANY = "any"


class ClassHierarchy:
    """Named groups of classes; a group may contain other groups (no cycles).

    Example: ClassHierarchy({"furniture": ["chair", "table", "seating"], "seating": ["couch"]}).
    """

    def __init__(self, groups: Mapping[str, Sequence[str]] = None):
        self.groups: Dict[str, List[str]] = {}
        for name, members in dict(groups or {}).items():
            if not isinstance(name, str) or not name or name == ANY:
                raise InvalidInputError(f"bad group name {name!r} in the class hierarchy")
            if isinstance(members, str) or not all(isinstance(m, str) and m for m in members):
                raise InvalidInputError(f"group {name!r} must list class names, got {members!r}")
            self.groups[name] = list(members)
        for name in self.groups:
            self._leaves(name, ())

    def _leaves(self, name: str, path: Sequence[str]) -> Set[str]:
        if name in path:
            raise InvalidInputError(f"cycle in the class hierarchy: {' -> '.join(list(path) + [name])}")
        if name not in self.groups:
            return {name}
        leaves: Set[str] = set()
        for member in self.groups[name]:
            leaves |= self._leaves(member, tuple(path) + (name,))
        return leaves

    def is_group(self, name: str) -> bool:
        return name in self.groups

    def expand(self, name: str) -> Set[str]:
        """The classes a name stands for: a group's classes (recursively) or the class itself."""
        return self._leaves(name, ())

    def groups_of(self, class_name: str) -> List[str]:
        """Every group that covers `class_name`, directly or through other groups."""
        return sorted(group for group in self.groups if class_name in self.expand(group))

    @property
    def classes(self) -> Set[str]:
        """Every class named in some group."""
        found: Set[str] = set()
        for group in self.groups:
            found |= self.expand(group)
        return found

    def resolve(self, name: str, known_classes: Iterable[str]) -> List[str]:
        """The classes to search for `name`: "any" -> every known class; a group -> its classes
        (also those not seen yet); a class -> itself.

        Raises UnknownNameError when the name is neither "any", a group, a known class nor a
        class of the hierarchy.
        """
        known = set(known_classes)
        if not isinstance(name, str) or not name.strip():
            raise UnknownNameError("empty class name (give a class, a group or 'any')")
        if name == ANY:
            return sorted(known)
        if name in self.groups:
            return sorted(self.expand(name))
        if name in known or name in self.classes:
            return [name]
        raise UnknownNameError(f"unknown class {name!r}; known classes: {', '.join(sorted(known)) or 'none'}"
                               f"; groups: {', '.join(sorted(self.groups)) or 'none'}")

    def to_dict(self) -> Dict[str, List[str]]:
        return {name: list(members) for name, members in self.groups.items()}
