"""The parameters of ros_mongo's nodes, one `NodeConfig` class per node (no ROS).

`RecorderParams` (ros_mongo_server), `RetrieverParams` (ros_mongo_retriever), `ReplicatorParams`
(ros_mongo_replicator) and `CentralSourceParams` (the base of learner nodes that can read the
central fleet database). Each default and description is written here once; the YAML files in
config/ are generated from these classes (`python -m robot_common.config_files --write`).
"""
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Dict, List, Optional, Sequence

from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param
from ros_mongo.errors import QueryError
from ros_mongo.messages.decoding import DECODE_LEVELS, DecodePolicy
from ros_mongo.query import Query, parse_query, query_from_mapping
from ros_mongo.recording.chunker import ChunkPolicy
from ros_mongo.recording.limits import DEFAULT_MAX_BYTES, DEFAULT_MIN_FREE_BYTES, DROPPABLE_TYPES
from ros_mongo.urls import redact_url, with_credentials

if TYPE_CHECKING:  # the spool and the changes follower load only when a node asks for them
    from ros_mongo.fleet.changes import ChangesFollower
    from ros_mongo.recording.bounded_spool import DropPolicy
    from ros_mongo.recording.upload_rules import UploadRules

__all__ = ["RecorderParams", "RetrieverParams", "ReplicatorParams", "CentralSourceParams", "SOURCES",
           "ORIGINAL_TOPICS", "ORIGINAL_TAGS", "configured_query", "compile_patterns"]

ORIGINAL_TOPICS = ["/camera/rgb/image_raw", "/joint_states", "/scan", "/odom"]
ORIGINAL_TAGS = {"/camera/rgb/image_raw": ["image"], "/joint_states": ["joint_states"],
                 "/scan": ["lidar"], "/odom": ["odom"]}


@dataclass
class RecorderParams(NodeConfig):
    """The ros_mongo_server node's parameters (the recorder)."""

    db_url: str = param("http://127.0.0.1:5984/robot_data",
                        "http(s):// CouchDB or mongodb:// MongoDB database URL")
    db_credentials_file: str = param("", "a file holding 'user:password' (or 'password') for db_url, so "
                                         "the password stays out of db_url, ps and parameter listings; "
                                         "empty: the environment's ROS_MONGO_DB_PASSWORD, if set")
    topics: List[str] = param(ORIGINAL_TOPICS, "topics always recorded (the four original ones)")
    include: List[str] = param([], "regular expressions: also record published topics whose name "
                                   "matches one")
    skip_topics: List[str] = param([], "topics never recorded (exact names; fleet.launch's local_topics "
                                       "when there is no local store)")
    exclude: List[str] = param(["^/rosout", "_mongo$", "^/diagnostics", "^/clock$"],
                               "regular expressions: never record topics whose name matches one")
    tcp_nodelay: bool = param(False, "ask publishers for TCP_NODELAY (as rosbag record --tcpnodelay): each "
                                     "message sent at once, receive times closer to publishing, more CPU "
                                     "at high rates")
    discovery_period: float = param(1.0, "seconds between looks for new publishers (with include)")
    batch_size: int = param(500, "messages per bulk write, at most")
    batch_period: float = param(0.2, "seconds a message waits for its bulk write, at most")
    max_queue_mb: float = param(1024.0, "received data waiting in memory (MB); beyond it messages go "
                                        "to the spool undecoded, so a slow database costs no messages")
    retry_period: float = param(1.0, "seconds between probes while the database is unreachable")
    writers: int = param(2, "writer threads (one encodes while another waits for the database)")
    spool_path: str = param("", "the spool file for database outages; empty: "
                                "$ROS_HOME/ros_mongo/<node>.spool")
    spool_fsync: bool = param(False, "fsync every spool append (survives power loss, not only a crash)")
    spool_max_mb: float = param(DEFAULT_MAX_BYTES / 2 ** 20, "the spool's size limit on disk (MB); when "
                                                             "full, the oldest messages of the droppable "
                                                             "topics go first (counted per topic)")
    spool_drop_types: List[str] = param(list(DROPPABLE_TYPES), "message types whose oldest messages "
                                                               "are dropped first when the spool is full "
                                                               "(every other topic is kept)")
    spool_drop_topics: List[str] = param([], "regular expressions: topics also dropped oldest-first "
                                             "when the spool is full")
    spool_min_free_mb: float = param(DEFAULT_MIN_FREE_BYTES / 2 ** 20,
                                     "free disk space (MB) the spool always leaves, like rosbag record "
                                     "--min-space")
    quarantine_path: str = param("", "where documents the database refuses on their own merits are "
                                     "kept; empty: <spool_path>.quarantine")
    db_tls_ca_file: str = param("", "CouchDB over https: a CA bundle for a private CA (empty: the "
                                    "system's); MongoDB: use the URL option tlsCAFile")
    db_tls_cert_file: str = param("", "CouchDB over https: a client certificate (PEM); MongoDB: the "
                                      "URL option tlsCertificateKeyFile")
    db_tls_key_file: str = param("", "CouchDB over https: the client certificate's key (PEM), if not "
                                     "in db_tls_cert_file")
    session_id: str = param("", "session id on every message; empty: <start time>-<node>")
    robot_id: str = param("", "robot id on every message; empty: the host name")
    tags: List[str] = param([], "tags on every message")
    author: str = param("", "author on every message (queried as 'author <name>'); empty: none")
    topic_tags: Dict[str, List[str]] = param(ORIGINAL_TAGS, "tags per topic (the original "
                                                            "image/joint_states/lidar/odom)")
    decode: Dict[str, str] = param({}, "per topic or message type: how much is decoded into queryable "
                                       "fields, full | index (no arrays) | raw (none); the bytes are "
                                       "always stored (topics without their leading '/': the parameter "
                                       "server drops such keys)")
    decode_default: str = param("full", "the decode level of topics and types not in ~decode",
                                choices=DECODE_LEVELS)
    blob_threshold: int = param(262144, "serialized messages larger than this (bytes) go to "
                                        "attachments / GridFS")
    chunk_topics: List[str] = param([], "regular expressions matching whole topic names: these topics "
                                        "are stored as chunks, one CouchDB document per topic per second "
                                        "or per chunk_messages (far less server CPU for small messages; "
                                        "see the README for the queries they answer)")
    chunk_rate: float = param(0.0, "also chunk every topic once it receives this many messages within "
                                   "one second (0.0: by chunk_topics only)")
    chunk_messages: int = param(1000, "messages per chunk, at most")
    chunk_period: float = param(1.0, "seconds a chunk stays open at most (0 < chunk_period <= 1.0): "
                                     "lower delivers chunked topics sooner, in more documents")
    upload_rules: str = param("", "a YAML file of per-topic upload rules (live, when: kept on the robot "
                                  "until docked / a daily window, local: never sent); empty: every "
                                  "topic live. For a recorder writing to central (fleet.launch)")
    upload_max_bytes_per_s: float = param(0.0, "the cap on all uploads of this recorder (bytes per "
                                               "second, as estimated from the messages); live topics "
                                               "first, released deferred data with the rest; 0.0: none",
                                          minimum=0.0)
    ledger_period: float = param(5.0, "seconds between saves of the upload ledger "
                                      "(<spool_path>.ledger) and its values on /diagnostics",
                                 minimum=0.1)
    db_timeout: float = param(5.0, "seconds a database request may take")
    diagnostics_period: float = param(1.0, "seconds between /diagnostics messages")
    log_period: float = param(10.0, "seconds between count lines in the log (when they changed)")
    shutdown_timeout: float = param(10.0, "seconds to flush and drain on shutdown")

    def check(self) -> None:
        compile_patterns("include", self.include)
        compile_patterns("exclude", self.exclude)
        compile_patterns("spool_drop_topics", self.spool_drop_topics)
        self.decode_policy()
        self.chunk_policy()
        self.upload_policy()
        if self.spool_max_mb <= 0 or self.spool_min_free_mb < 0:
            raise ConfigError(f"~spool_max_mb must be positive and ~spool_min_free_mb not negative, got "
                              f"{self.spool_max_mb!r} and {self.spool_min_free_mb!r}")
        tls = [self.db_tls_ca_file, self.db_tls_cert_file, self.db_tls_key_file]
        if any(tls) and not self.db_url.lower().startswith("https://"):
            raise ConfigError("~db_tls_ca_file / ~db_tls_cert_file / ~db_tls_key_file need an https:// "
                              "CouchDB ~db_url (MongoDB takes its TLS options in the URL)")

    def decode_policy(self) -> DecodePolicy:
        """The ~decode levels (ConfigError naming a bad one)."""
        try:
            return DecodePolicy(_flat(self.decode), self.decode_default)
        except ValueError as err:
            raise ConfigError(f"~decode: {err}") from None

    def chunk_policy(self) -> ChunkPolicy:
        """Which topics are stored as chunks (ConfigError naming a bad setting)."""
        compile_patterns("chunk_topics", self.chunk_topics)
        try:
            return ChunkPolicy(self.chunk_topics, self.chunk_rate, self.chunk_messages, self.chunk_period)
        except ValueError as err:
            raise ConfigError(f"~chunk_rate / ~chunk_messages / ~chunk_period: {err}") from None

    def upload_policy(self) -> "UploadRules":
        """The upload rules of ~upload_rules (ConfigError naming a bad file or value)."""
        from ros_mongo.recording.upload_rules import load_upload_rules
        return load_upload_rules(self.upload_rules)

    def drop_policy(self) -> "DropPolicy":
        """Which topics lose their oldest messages first when the spool is full."""
        from ros_mongo.recording.bounded_spool import DropPolicy
        return DropPolicy(self.spool_drop_types, self.spool_drop_topics)

    def store_options(self) -> Dict[str, object]:
        """open_store options (the TLS ones only where set; the credentials file, if any)."""
        options: Dict[str, object] = {"timeout": self.db_timeout, "blob_threshold": self.blob_threshold,
                                      "credentials_file": self.db_credentials_file or None}
        for key, value in (("tls_ca_file", self.db_tls_ca_file), ("tls_cert_file", self.db_tls_cert_file),
                           ("tls_key_file", self.db_tls_key_file)):
            if value:
                options[key] = value
        return options


def compile_patterns(name: str, values: List[str]) -> List["re.Pattern"]:
    """The regular expressions of the parameter `name` (ConfigError naming a bad one)."""
    try:
        return [re.compile(v) for v in values]
    except (re.error, TypeError) as err:
        raise ConfigError(f"~{name} holds a bad regular expression: {err}") from None



@dataclass
class RetrieverParams(NodeConfig):
    """The ros_mongo_retriever node's parameters (replay)."""

    db_url: str = param("http://127.0.0.1:5984/robot_data",
                        "http(s):// CouchDB or mongodb:// MongoDB database URL, password-free (a "
                        "password here shows in parameter listings: use db_credentials_file)")
    db_credentials_file: str = param("", "file holding 'user:password' or 'password' for db_url "
                                         "(empty: $ROS_MONGO_DB_PASSWORD, if set)")
    query: str = param("", "YAML/JSON query mapping or the original '<key> <value>' form ('tags "
                           "lidar', 'author ServiceRobot'); its keys override the query parameters below")
    require_query: bool = param(False, "refuse to start without ~query, as the original's "
                                       "retrieve.launch did (which sets it)")
    topics: List[str] = param([], "query: only these topics (empty: all)")
    type: str = param("", "query: only this message type (empty: any)")
    tags: List[str] = param([], "query: only messages with all these tags")
    session_id: str = param("", "query: only this session (empty: any)")
    robot_id: str = param("", "query: only this robot (empty: any)")
    start_time: float = param(0.0, "query: receive time from (seconds; 0.0: open)")
    end_time: float = param(0.0, "query: receive time until (seconds; 0.0: open)")
    fields: Dict[str, Any] = param({}, "query: conditions on decoded message fields")
    output_suffix: str = param("_mongo", "/scan is replayed on /scan<output_suffix>")
    rate: float = param(1.0, "speed factor of the recorded timing")
    start_offset: float = param(0.0, "seconds of the recording skipped at its start")
    duration: float = param(0.0, "seconds of the recording played (0.0: all)")
    loop: bool = param(False, "play again from the start when done")
    fixed_rate: float = param(0.0, "messages per second instead of the recorded timing (0.0: off)")
    publish_clock: bool = param(False, "publish /clock with the recorded time")
    clock_rate: float = param(100.0, "/clock messages per second")
    autostart: bool = param(True, "start playing at launch")
    start_delay: float = param(1.0, "autostart: seconds given to subscribers launched alongside to "
                                    "register, then at most as long again for the subscribers the "
                                    "master knows of to connect")
    prefetch: int = param(100000, "messages read ahead, at most (filled before playing)")
    prefetch_mb: float = param(1024.0, "MB read ahead, at most")
    preroll_timeout: float = param(60.0, "longest wait (s) for the read-ahead before playing (loading while "
                                         "playing costs timing on a busy machine)")
    queue_size: int = param(100, "outgoing queue per subscriber of topics above sync_max_bytes")
    sync_max_bytes: int = param(16777216, "topics with larger messages are published through a queue; "
                                          "smaller ones synchronously (exact timing)")
    lane_min_bytes: int = param(65536, "messages this large are published by a thread of their "
                                       "topic's own, so writing them does not delay other topics")
    db_timeout: float = param(10.0, "seconds a database request may take")

    def check(self) -> None:
        if self.require_query and not self.query.strip():
            raise ConfigError("no query given: retrieve.launch needs one, e.g. query:='tags lidar' or "
                              "query:='author ServiceRobot' (to replay everything use "
                              "ros_mongo_retrieve.launch)")
        configured_query(self)


def configured_query(config: RetrieverParams) -> Query:
    """The query the retriever's parameters describe (~query's keys override the others;
    ConfigError)."""
    mapping = {"topics": config.topics, "type": config.type, "tags": config.tags,
               "session_id": config.session_id, "robot_id": config.robot_id,
               "start_time": config.start_time or None, "end_time": config.end_time or None,
               "fields": config.fields or None, "author": None}
    try:
        if config.query.strip():
            text_query = parse_query(config.query)
            mapping.update({k: v for k, v in _as_mapping(text_query).items() if v not in (None, [], {})})
        return query_from_mapping(mapping)
    except QueryError as err:
        raise ConfigError(f"bad query: {err}") from None


def _as_mapping(query: Query) -> Dict[str, Any]:
    return {"topics": query.topics, "type": query.msg_type, "tags": query.tags,
            "session_id": query.session_id, "robot_id": query.robot_id, "start_time": query.start_time,
            "end_time": query.end_time, "fields": query.fields, "author": query.author}


@dataclass
class ReplicatorParams(NodeConfig):
    """The ros_mongo_replicator node's parameters (local store -> central replication)."""

    local_url: str = param("http://127.0.0.1:5984/robot_data",
                           "the robot's CouchDB-API database that the recorder writes (password-free)")
    central_url: str = param("", "the central CouchDB database URL, e.g. http://central:5984/fleet "
                                 "(password-free; required)")
    central_credentials_file: str = param("", "file with user:password for central_url (or set "
                                              "ROS_MONGO_CENTRAL_USER / ROS_MONGO_CENTRAL_PASSWORD)")
    robot_id: str = param("", "this robot's id (names the replication); empty: the host name")
    topics: List[str] = param([], "topics whose documents go up; empty: every recorded topic")
    local_topics: List[str] = param([], "topics that stay on the robot (e.g. camera images)")
    create_central_db: bool = param(True, "create the central database if missing (needs an admin "
                                          "account on CouchDB 3; otherwise an admin creates it)")
    autostart: bool = param(True, "start the replication when the node starts")
    status_period: float = param(1.0, "seconds between checks and /diagnostics messages", minimum=0.1)
    lag_warn: float = param(30.0, "seconds of lag above which the status is WARN", minimum=0.0)
    max_tracked: int = param(100000, "pending documents followed one by one (beyond: estimated)",
                             minimum=1)
    retention_age: float = param(0.0, "delete local messages held centrally and older than this "
                                      "(seconds); 0: keep everything", minimum=0.0)
    retention_period: float = param(60.0, "seconds between retention passes", minimum=1.0)
    retention_batch: int = param(5000, "documents read per retention pass, at most", minimum=1)
    timeout: float = param(10.0, "seconds a database request may take", minimum=0.1)
    central_tls_ca_file: str = param("", "central over https: a CA bundle for a private CA (empty: "
                                         "the system's); the robot's store verifies with its own")
    central_tls_cert_file: str = param("", "central over https: a client certificate (PEM)")
    central_tls_key_file: str = param("", "central over https: the client certificate's key (PEM), "
                                          "if not in central_tls_cert_file")

    def central_tls(self) -> Dict[str, str]:
        """The TLS options of the central database for ros_mongo.storage.couch_client (given ones only)."""
        given = (("tls_ca_file", self.central_tls_ca_file), ("tls_cert_file", self.central_tls_cert_file),
                 ("tls_key_file", self.central_tls_key_file))
        return {key: value for key, value in given if value}

    def check(self) -> None:
        if not self.central_url:
            raise ConfigError("~central_url is required (the central CouchDB database URL)")
        for name, value in (("local_url", self.local_url), ("central_url", self.central_url)):
            if not value.startswith(("http://", "https://")):
                raise ConfigError(f"~{name} must be an http(s):// CouchDB database URL, got "
                                  f"{redact_url(value)!r}")


SOURCES = ("topic", "central")  # where a learner's messages come from


@dataclass
class CentralSourceParams(NodeConfig):
    """The parameters of a learner node that can learn from the central fleet database instead
    of its topics (subclass it: the node's own parameters follow these)."""

    source: str = param("topic", "where the learner's messages come from: its topics (topic) or "
                                 "the central fleet database's _changes feed, every robot's "
                                 "messages (central)", choices=SOURCES)
    central_url: str = param("", "source central: the central CouchDB database URL, e.g. "
                                 "http://central:5984/fleet (password-free)")
    central_credentials_file: str = param("", "source central: file with user:password for "
                                              "central_url (or ROS_MONGO_DB_USER / "
                                              "ROS_MONGO_DB_PASSWORD in the environment)")
    central_topics: List[str] = param([], "source central: recorded topics of the messages to "
                                          "learn from; empty: every topic")

    def check(self) -> None:
        if self.source == "central" and not self.central_url.startswith(("http://", "https://")):
            raise ConfigError("~central_url must be the central CouchDB database URL "
                              "(http:// or https://) when ~source is central")

    def central_follower(self, types: Sequence[str], since: Any = 0,
                         topics: Optional[Sequence[str]] = None) -> "ChangesFollower":
        """A follower of the central feed's message documents of `types` on `topics` (default:
        `central_topics`; empty: every topic), from `since`, with the credentials of
        `central_credentials_file`."""
        url = with_credentials(self.central_url,
                               credentials_file=self.central_credentials_file or None)
        selector: Dict[str, Any] = {"type": {"$in": list(types)}}
        topics = self.central_topics if topics is None else topics
        if topics:
            selector["topic"] = {"$in": list(topics)}
        from ros_mongo.fleet.changes import ChangesFollower
        return ChangesFollower(url, selector=selector, since=since)


def _flat(levels: dict, prefix: str = "") -> dict:
    """~decode as the parameter server returns it, flattened: it nests a key holding '/'
    ({nav_msgs: {Odometry: index}} is nav_msgs/Odometry; {camera: {rgb: ...}} camera/rgb...)."""
    flat = {}
    for key, value in levels.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flat(value, name + "/"))
        else:
            flat[name] = value
    return flat
