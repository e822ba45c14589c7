"""Per-topic upload rules of a fleet robot (no ROS): which topics go to central at once, which wait
on the robot until a condition holds, which never leave it.

The rules file (YAML), read once at start; any error in it is a ConfigError naming the bad value:

    rules:                            # in order: the first rule whose pattern matches a topic wins
      - topics: ^/(odom|scan)$        # a regular expression searched in the topic name, or a list
        upload: live                  # straight to central (the spool is the buffer, as always)
      - name: camera                  # optional: names the rule's part of the spool (default ruleN)
        topics: ^/camera/
        upload: when                  # kept on the robot's disk, uploaded only while `when` holds
        when:                         # every condition given must hold
          docked: /battery_state      # std_msgs/Bool (true: docked) or sensor_msgs/BatteryState
                                      # (power_supply_status CHARGING or FULL)
          window: "22:00-06:00"       # a daily window of local time (may wrap midnight)
        max_mb: 2048                  # the bound of this rule's part of the spool (default 1024)
      - name: bumper_camera
        topics: ^/camera/
        upload: on_event              # the last `before` seconds on the robot's disk; a trigger
        event: {before: 30, after: 10}  # keeps [t - before, t + after], the rest is recycled
        when: {docked: /battery_state}  # optional: kept windows wait for it (default: at once)
      - topics: [^/debug/, ^/tf_static$]
        upload: local                 # never leaves the robot
    default: live                     # the rule of topics no rule matches: live or local
"""
import datetime
import re
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

import yaml

from robot_common.errors import ConfigError

__all__ = ["UploadRules", "UploadRule", "Condition", "DailyWindow", "load_upload_rules",
           "parse_upload_rules", "docked_from_battery", "MODES", "DEFAULT_PART_MB"]

MODES = ("live", "when", "on_event", "local")
DEFAULT_PART_MB = 1024.0
_RULE_KEYS = {"name", "topics", "upload", "when", "max_mb", "event"}
_WHEN_KEYS = {"docked", "window"}
_NAME_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_CLOCK_RE = re.compile(r"^(\d{1,2}):(\d{2})$")
#: sensor_msgs/BatteryState power_supply_status values that mean "on the charger".
CHARGING_STATES = (1, 4)  # POWER_SUPPLY_STATUS_CHARGING, POWER_SUPPLY_STATUS_FULL


def docked_from_battery(power_supply_status: int) -> bool:
    """Whether a sensor_msgs/BatteryState's power_supply_status means the robot is on its charger."""
    return int(power_supply_status) in CHARGING_STATES


class DailyWindow:
    """A daily window of local time, `start` included, `end` excluded; it wraps midnight when end
    is before start ("22:00-06:00"); equal ends mean the whole day."""

    def __init__(self, text: str):
        parts = str(text).split("-")
        if len(parts) != 2:
            raise ConfigError(f"upload rules: bad window {text!r}: expected 'HH:MM-HH:MM'")
        self.text = str(text)
        self.start, self.end = (_minutes(part.strip(), text) for part in parts)

    def contains(self, now: datetime.time) -> bool:
        minute = now.hour * 60 + now.minute
        if self.start == self.end:
            return True
        if self.start < self.end:
            return self.start <= minute < self.end
        return minute >= self.start or minute < self.end


def _minutes(clock: str, text: str) -> int:
    match = _CLOCK_RE.match(clock)
    if not match or int(match.group(1)) > 23 or int(match.group(2)) > 59:
        raise ConfigError(f"upload rules: bad window {text!r}: {clock!r} is not a time HH:MM "
                          f"(00:00 to 23:59)")
    return int(match.group(1)) * 60 + int(match.group(2))


class Condition:
    """When a deferred rule's data may go up: docked (the state last read from `docked`'s topic;
    unknown counts as not docked) and / or inside a daily window."""

    def __init__(self, docked: Optional[str] = None, window: Optional[DailyWindow] = None):
        self.docked, self.window = docked, window

    def holds(self, docked: Dict[str, bool], now: datetime.time) -> bool:
        """`docked`: the latest state per dock topic; `now`: the local time of day."""
        if self.docked is not None and not docked.get(self.docked, False):
            return False
        return self.window is None or self.window.contains(now)

    def describe(self) -> str:
        parts = ([f"docked ({self.docked})"] if self.docked else []) + \
                ([f"within {self.window.text}"] if self.window else [])
        return " and ".join(parts) or "at once"


class UploadRule:
    """One rule: the topics it matches, its mode, and for `when` its condition and spool bound."""

    def __init__(self, name: str, patterns: Sequence[str], mode: str,
                 condition: Optional[Condition] = None, max_mb: float = DEFAULT_PART_MB,
                 before: float = 0.0, after: float = 0.0):
        self.name, self.mode, self.condition, self.max_mb = name, mode, condition, float(max_mb)
        self.before, self.after = float(before), float(after)  # on_event: the window
        self.pattern_texts = list(patterns)
        self.patterns = [re.compile(p) for p in patterns]

    def matches(self, topic: str) -> bool:
        return any(p.search(topic) for p in self.patterns)


class UploadRules:
    """Rules in order plus the default mode; `rule_for(topic)` is the first match (cached)."""

    def __init__(self, rules: Sequence[UploadRule] = (), default: str = "live"):
        self.rules, self.default = list(rules), UploadRule("default", [], default)
        self._cache: Dict[str, UploadRule] = {}

    def rule_for(self, topic: str) -> UploadRule:
        rule = self._cache.get(topic)
        if rule is None:
            rule = next((r for r in self.rules if r.matches(topic)), self.default)
            self._cache[topic] = rule
        return rule

    def mode(self, topic: str) -> str:
        return self.rule_for(topic).mode

    @property
    def deferred(self) -> List[UploadRule]:
        """The rules whose data waits on the robot (on_event first, then when; each in order)."""
        return [r for r in self.rules if r.mode == "on_event"] + \
            [r for r in self.rules if r.mode == "when"]

    @property
    def events(self) -> List[UploadRule]:
        """The on_event rules, in order."""
        return [r for r in self.rules if r.mode == "on_event"]

    @property
    def dock_topics(self) -> List[str]:
        return sorted({r.condition.docked for r in self.deferred if r.condition.docked})


def load_upload_rules(path: Union[str, Path, None]) -> UploadRules:
    """The rules of a YAML file (empty path: every topic live); ConfigError for any error."""
    if not path:
        return UploadRules()
    try:
        text = Path(path).read_text()
    except OSError as err:
        raise ConfigError(f"cannot read the upload rules file {path}: {err.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f"upload rules file {path} is not valid YAML: {err}") from None
    try:
        return parse_upload_rules(data)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


def parse_upload_rules(data) -> UploadRules:
    """The rules of a parsed rules document (see the module docstring); ConfigError naming the bad
    value."""
    if not isinstance(data, dict) or "rules" not in data:
        raise ConfigError(f"upload rules: expected a mapping with 'rules' (and optionally "
                          f"'default'), got {data!r:.200}")
    unknown = set(data) - {"rules", "default"}
    if unknown:
        raise ConfigError(f"upload rules: unknown keys {sorted(unknown)} (known: rules, default)")
    default = data.get("default", "live")
    if default not in ("live", "local"):
        raise ConfigError(f"upload rules: default must be live or local, got {default!r}")
    if not isinstance(data["rules"], list):
        raise ConfigError(f"upload rules: 'rules' must be a list, got {data['rules']!r:.200}")
    rules = [_rule(index, item) for index, item in enumerate(data["rules"], 1)]
    names = [r.name for r in rules]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ConfigError(f"upload rules: rule names must be unique, repeated: {repeated}")
    return UploadRules(rules, default)


def _rule(index: int, item) -> UploadRule:
    where = f"upload rules: rule {index}"
    if not isinstance(item, dict):
        raise ConfigError(f"{where}: expected a mapping, got {item!r:.200}")
    unknown = set(item) - _RULE_KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (known: {sorted(_RULE_KEYS)})")
    name = str(item.get("name", f"rule{index}"))
    if not _NAME_RE.match(name):
        raise ConfigError(f"{where}: bad name {name!r} (letters, digits, _ and -, at most 64)")
    patterns = item.get("topics")
    patterns = [patterns] if isinstance(patterns, str) else patterns
    if not patterns or not isinstance(patterns, list) or not all(isinstance(p, str) for p in patterns):
        raise ConfigError(f"{where}: 'topics' must be a regular expression or a non-empty list of "
                          f"them, got {item.get('topics')!r}")
    for pattern in patterns:
        try:
            re.compile(pattern)
        except re.error as err:
            raise ConfigError(f"{where}: bad regular expression {pattern!r}: {err}") from None
    mode = item.get("upload")
    if mode not in MODES:
        raise ConfigError(f"{where}: unknown upload mode {mode!r} (known: {', '.join(MODES)})")
    if mode in ("live", "local"):
        if {"when", "max_mb", "event"} & set(item):
            raise ConfigError(f"{where}: 'when', 'event' and 'max_mb' belong to upload: when / "
                              f"on_event rules, not {mode!r}")
        return UploadRule(name, patterns, mode)
    if mode == "when" and "event" in item:
        raise ConfigError(f"{where}: 'event' belongs to upload: on_event rules")
    before, after = _event(where, item.get("event")) if mode == "on_event" else (0.0, 0.0)
    when = item.get("when") if mode == "when" or "when" in item else None
    condition = _condition(where, when) if when is not None or mode == "when" else Condition()
    return UploadRule(name, patterns, mode, condition,
                      _max_mb(where, item.get("max_mb", DEFAULT_PART_MB)), before, after)


def _event(where: str, event) -> tuple:
    if not isinstance(event, dict) or set(event) != {"before", "after"}:
        raise ConfigError(f"{where}: upload: on_event needs 'event' with before and after "
                          f"(seconds), got {event!r}")
    for key in ("before", "after"):
        value = event[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0 \
                or (key == "before" and value <= 0):
            raise ConfigError(f"{where}: event '{key}' must be a number of seconds (before > 0, "
                              f"after >= 0), got {value!r}")
    return float(event["before"]), float(event["after"])


def _condition(where: str, when) -> Condition:
    if not isinstance(when, dict) or not when:
        raise ConfigError(f"{where}: upload: when needs 'when' with docked and / or window, got "
                          f"{when!r}")
    unknown = set(when) - _WHEN_KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown conditions {sorted(unknown)} (known: docked, window)")
    docked = when.get("docked")
    if docked is not None and (not isinstance(docked, str) or not docked.startswith("/")):
        raise ConfigError(f"{where}: 'docked' must be a topic name starting with '/', got {docked!r}")
    window = when.get("window")
    return Condition(docked, DailyWindow(window) if window is not None else None)


def _max_mb(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value <= 0:
        raise ConfigError(f"{where}: 'max_mb' must be a positive number, got {value!r}")
    return float(value)
