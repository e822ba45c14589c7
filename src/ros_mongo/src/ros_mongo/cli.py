"""`ros_mongo_bag`: bags and MCAP files into the database and back, with a progress bar.

    ros_mongo_bag import run1.bag run2.mcap --db-url http://127.0.0.1:5984/robot_data --tags lab
    ros_mongo_bag export out.bag --db-url mongodb://127.0.0.1:27017/robot_data --query "tags lidar"
    ros_mongo_bag export session.mcap --session-id run1     (MCAP for Foxglove; or --format mcap)
    ros_mongo_bag import crashed.bag.active       (an unindexed bag: recovers what is readable)
    ros_mongo_bag info --db-url http://127.0.0.1:5984/robot_data
    ros_mongo_bag setup --db-url http://admin@127.0.0.1:5984/robot_data --db-credentials-file ~/.admin
    ros_mongo_bag migrate --from-url mongodb://127.0.0.1:27017 --db-url mongodb://127.0.0.1:27017/test_database
    ros_mongo_bag convert --query "tags lidar"     (bag_converter.launch: the original's defaults)
    ros_mongo_bag ledger ~/.ros/ros_mongo/ros_mongo_server.spool   (a fleet robot's upload ledger)

Credentials: keep --db-url password-free (a password on the command line shows in `ps` and logs)
and give it through --db-credentials-file (one line, 'user:password' or 'password') or the
environment (ROS_MONGO_DB_PASSWORD, ROS_MONGO_DB_USER). The URL itself may also come from
ROS_MONGO_DB_URL. `setup` creates the indexes / design documents reads use; run it once with an
admin account, so that robots need only document-write rights and readers only read rights.
`migrate` reads the original mongodb_api's documents (test_database.posts) into today's layout,
saying per field what it reconstructed and what the original never stored; a re-run stores
nothing twice and rewrites nothing. `convert` is the original bag_converter: the original global
parameters where_to_write (write_bag: export, write_database: import), bag_name, server_ip, port
and session_id are honoured when set on the ROS master (each with a deprecation warning).
Exits 0 on success, 1 with one "ERROR: ..." line otherwise.
"""
import argparse
import os
import re
import sys
from pathlib import Path
from typing import List, Optional

from ros_mongo.compat.legacy import (
    DEFAULT_BAG_NAME,
    LEGACY_COLLECTION,
    LEGACY_DATABASE,
    WRITE_BAG,
    legacy_overrides,
    migrate_documents,
)
from ros_mongo.errors import StoreError
from ros_mongo.files.bagio import BATCH_BYTES, export_file, import_file
from ros_mongo.files.formats import format_names
from ros_mongo.query import parse_query, query_from_mapping
from ros_mongo.recording.allocator import keep_freed_memory
from ros_mongo.recording.ledger import format_ledger, read_ledger
from ros_mongo.storage.store import open_store
from ros_mongo.urls import PASSWORD_ENV, password_warning, redact_url

__all__ = ["main"]

DEFAULT_URL = "http://127.0.0.1:5984/robot_data"
URL_ENV = "ROS_MONGO_DB_URL"
_TLS_OPTIONS = (("ca", "a CA bundle for a private CA"), ("cert", "a client certificate (PEM)"),
                ("key", "the client certificate's key (PEM), if not in the certificate file"))


def parse_args(argv: List[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="ros_mongo_bag", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.splitlines()[1:]))
    parser.add_argument("--db-url", default=os.environ.get(URL_ENV) or DEFAULT_URL,
                        help=f"database URL, password-free (default ${URL_ENV}, else {DEFAULT_URL})")
    parser.add_argument("--db-credentials-file", default=None,
                        help=f"file holding 'user:password' or 'password' (else ${PASSWORD_ENV})")
    for name, meaning in _TLS_OPTIONS:
        parser.add_argument(f"--db-tls-{name}-file", default=None, help=f"https CouchDB: {meaning}")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    commands = parser.add_subparsers(dest="command", required=True)
    up = commands.add_parser("import", help="store the messages of bags or MCAP files")
    up.add_argument("bags", nargs="+", help="bag or MCAP files (recognised by their content; "
                                            "unindexed bags are recovered as far as readable)")
    up.add_argument("--topics", nargs="*", help="only these topics")
    up.add_argument("--tags", nargs="*", default=[], help="tags for every message")
    up.add_argument("--session-id", help="session id (default: the bag's file name)")
    up.add_argument("--robot-id", help="robot id")
    up.add_argument("--batch-mb", type=float, default=BATCH_BYTES / 2 ** 20,
                    help=f"MB of messages per write batch (default {BATCH_BYTES / 2 ** 20:g}; at most "
                         f"three batches are held at once)")
    down = commands.add_parser("export", help="write stored messages to a new bag or MCAP file")
    down.add_argument("bag", help="the file to write (refuses to overwrite without --force)")
    down.add_argument("--format", choices=format_names(), default=None, dest="file_format",
                      help="bag or mcap (default: mcap for a .mcap file name, else bag)")
    down.add_argument("--query", default="", help='YAML/JSON query or "<key> <value>" ("tags lidar")')
    down.add_argument("--topics", nargs="*", help="only these topics")
    down.add_argument("--tags", nargs="*", help="only messages with all these tags")
    down.add_argument("--session-id", help="only this session")
    down.add_argument("--start-time", type=float, help="receive time from (s)")
    down.add_argument("--end-time", type=float, help="receive time until (s)")
    down.add_argument("--compression", choices=["none", "bz2", "lz4", "zstd"], default="none",
                      help="bag: none, bz2 or lz4; mcap: none, lz4 or zstd (default none)")
    down.add_argument("--force", action="store_true", help="overwrite an existing bag")
    move = commands.add_parser("migrate", help="read the original mongodb_api's documents into today's "
                                               "layout")
    move.add_argument("--from-url", default="mongodb://127.0.0.1:27017",
                      help="the original's MongoDB (its server_ip and port), password-free")
    move.add_argument("--from-credentials-file", default=None,
                      help="file holding 'user:password' or 'password' for --from-url")
    move.add_argument("--from-db", default=LEGACY_DATABASE, help=f"its database (default {LEGACY_DATABASE})")
    move.add_argument("--from-collection", default=LEGACY_COLLECTION,
                      help=f"its collection (default {LEGACY_COLLECTION})")
    move.add_argument("--robot-id", help="robot id for the migrated messages (the original stored none)")
    convert = commands.add_parser("convert", help="the original bag_converter: export (write_bag) or "
                                                  "import (write_database) by its global parameters")
    convert.add_argument("--query", default="", help="the query to export ('tags lidar')")
    convert.add_argument("--direction", choices=["", "export", "import"], default="",
                         help="default: the global where_to_write, else export")
    convert.add_argument("--bag", default="", help="the bag (default: <bag-dir>/<global bag_name or "
                                                   f"{DEFAULT_BAG_NAME}>)")
    convert.add_argument("--bag-dir", default="", help="where the bag is (default $ROS_HOME/ros_mongo/bag)")
    convert.add_argument("--tags", nargs="*", default=[], help="import: tags for every message")
    convert.add_argument("--force", action="store_true", help="export: overwrite an existing bag")
    commands.add_parser("info", help="stored topics and message counts")
    commands.add_parser("setup", help="create the indexes / design documents (admin account, once)")
    ledger = commands.add_parser("ledger", help="a recorder's upload ledger per topic: recorded, "
                                                "uploaded, dropped (with the reason), waiting")
    ledger.add_argument("spool", help="the recorder's ~spool_path (its ledger is <spool>.ledger)")
    for sub in commands.choices.values():  # options work before or after the command
        sub.add_argument("--db-url", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        sub.add_argument("--db-credentials-file", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        for name, _ in _TLS_OPTIONS:
            sub.add_argument(f"--db-tls-{name}-file", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        sub.add_argument("--no-progress", action="store_true", default=argparse.SUPPRESS,
                         help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def _export_query(args: argparse.Namespace):
    query = parse_query(args.query)
    mapping = {"topics": args.topics or query.topics, "tags": args.tags or query.tags,
               "type": query.msg_type, "session_id": args.session_id or query.session_id,
               "robot_id": query.robot_id, "fields": query.fields or None,
               "start_time": args.start_time if args.start_time is not None else query.start_time,
               "end_time": args.end_time if args.end_time is not None else query.end_time,
               "author": query.author}
    return query_from_mapping(mapping)


def _master_params(names) -> dict:
    """The original global parameters set on the ROS master (none when no master is reachable)."""
    try:
        import rosgraph
        master = rosgraph.Master("/ros_mongo_bag")
        values = {}
        for name in names:
            if master.hasParam(name):
                values[name] = master.getParam(name)
        return values
    except Exception:  # noqa: BLE001 - no master: the command line alone decides
        return {}


def _convert_args(args: argparse.Namespace) -> argparse.Namespace:
    """The convert command as an export or import, with the original's defaults and globals."""
    from robot_common.paths import ros_home

    names = ("server_ip", "port", "bag_name", "where_to_write", "session_id")
    given = {"db_url": args.db_url, "direction": args.direction, "bag": args.bag}
    defaults = {"db_url": DEFAULT_URL, "direction": "", "bag": ""}
    overrides, warnings = legacy_overrides("converter", _master_params(names), given, defaults)
    for line in warnings:
        print(f"WARNING: {line}", file=sys.stderr)
    args.db_url = overrides.get("db_url", args.db_url)
    args.command = args.direction or overrides.get("direction") or "export"
    if args.command not in ("export", "import"):
        raise StoreError(f"where_to_write must be '{WRITE_BAG}' or 'write_database', got "
                         f"{args.command!r}")
    bag_dir = Path(args.bag_dir) if args.bag_dir else ros_home() / "ros_mongo" / "bag"
    bag = Path(args.bag or overrides.get("bag") or DEFAULT_BAG_NAME)
    bag = bag if bag.is_absolute() else bag_dir / bag
    if args.command == "export":
        if not args.query.strip():
            raise StoreError("no query given: the bag converter exports with one, e.g. query:='tags lidar'")
        bag.parent.mkdir(parents=True, exist_ok=True)
        return _namespace(args, bag=str(bag), topics=None, tags=None, session_id=None, start_time=None,
                          end_time=None, compression="none", file_format=None)
    return _namespace(args, bags=[str(bag)], topics=None, session_id=overrides.get("session_id"),
                      robot_id=None, batch_mb=BATCH_BYTES / 2 ** 20)


def _namespace(args: argparse.Namespace, **values) -> argparse.Namespace:
    merged = dict(vars(args))
    merged.update(values)
    return argparse.Namespace(**merged)


def _migrate(args: argparse.Namespace, store, progress: bool) -> None:
    import pymongo
    from tqdm import tqdm

    from ros_mongo.urls import scrub, with_credentials

    # only its own credentials file: the environment's password is the target's
    url = with_credentials(args.from_url, credentials_file=args.from_credentials_file, environ={})
    client = pymongo.MongoClient(url, serverSelectionTimeoutMS=10000)
    try:
        collection = client[args.from_db][args.from_collection]
        total = collection.estimated_document_count()
        print(f"migrating {total} documents of {redact_url(args.from_url)} "
              f"{args.from_db}.{args.from_collection} into {store.url}")
        with tqdm(total=total, unit="doc", desc="migrate", disable=not progress) as bar:
            report = migrate_documents(collection.find().sort("_id", 1), store, robot_id=args.robot_id,
                                       on_progress=bar.update)
    except pymongo.errors.PyMongoError as err:
        raise StoreError(f"cannot read {redact_url(args.from_url)} {args.from_db}.{args.from_collection}: "
                         f"{type(err).__name__}: {scrub(str(err), url)}") from None
    finally:
        client.close()
    for line in report.lines():
        print(line)


def _tls(args: argparse.Namespace) -> dict:
    """The given --db-tls-*-file options as open_store's tls_*_file (https CouchDB only)."""
    given = {f"tls_{name}_file": getattr(args, f"db_tls_{name}_file", None) for name, _ in _TLS_OPTIONS}
    given = {key: value for key, value in given.items() if value}
    if given and not args.db_url.lower().startswith("https://"):
        raise StoreError("--db-tls-ca-file / --db-tls-cert-file / --db-tls-key-file need an https:// "
                         "CouchDB URL (MongoDB: the URL options tlsCAFile, tlsCertificateKeyFile)")
    return given


def run(args: argparse.Namespace) -> None:
    progress = not args.no_progress
    warning = password_warning(args.db_url,
                               hint=f"in a file given as --db-credentials-file or in ${PASSWORD_ENV}")
    if warning:  # once: opening the store does not repeat it
        print(f"WARNING: {warning}", file=sys.stderr)
    if args.command == "ledger":  # a file on the robot: no database
        print(format_ledger(read_ledger(args.spool + ".ledger")))
        return
    if args.command == "convert":
        args = _convert_args(args)
    with open_store(args.db_url, credentials_file=args.db_credentials_file, **_tls(args)) as store:
        if args.command == "migrate":
            _migrate(args, store, progress)
        elif args.command == "setup":
            if store.ensure_indexes():
                print(f"{store.url}: indexes ready")
            else:
                raise StoreError(f"{store.url}: this account may not create indexes; run setup with an "
                                 f"admin account")
        elif args.command == "import":
            if not args.batch_mb > 0:
                raise StoreError(f"--batch-mb must be positive, got {args.batch_mb!r}")
            for bag in args.bags:
                result = import_file(bag, store, topics=args.topics, tags=args.tags,
                                     session_id=args.session_id, robot_id=args.robot_id, progress=progress,
                                     batch_bytes=int(args.batch_mb * 2 ** 20))
                if result.recovery is not None:
                    print(f"WARNING: {bag}: {result.recovery.describe()}", file=sys.stderr)
                print(f"{bag}: {result.messages} messages, {result.bytes / 1e6:.1f} MB in "
                      f"{result.seconds:.1f} s ({result.rate:.0f} msg/s, {result.megabytes_per_second:.1f} "
                      f"MB/s) into {store.url}")
        elif args.command == "export":
            query = _export_query(args)
            result = export_file(store, query, args.bag, file_format=args.file_format,
                                 overwrite=args.force, compression=args.compression, progress=progress)
            print(f"{args.bag}: {result.messages} messages ({query.describe()}), "
                  f"{result.bytes / 1e6:.1f} MB in {result.seconds:.1f} s")
        else:
            for info in store.topics():
                count = store.count(query_from_mapping({"topics": [info.topic], "type": info.msg_type}))
                print(f"{info.topic:32s} {info.msg_type:32s} {count:8d} messages"
                      f"{'  (latched)' if info.latching else ''}")


def main(argv: Optional[List[str]] = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    argv = [a for a in argv if not re.match(r"^__\w+:=", a)]  # roslaunch's __name:= and __log:=
    args = parse_args(argv)
    keep_freed_memory()  # image-sized buffers reuse memory instead of fresh pages (recording.allocator)
    try:
        run(args)
    except StoreError as err:  # SpoolError (the ledger) is one
        print(f"ERROR: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("ERROR: interrupted", file=sys.stderr)
        return 1
    return 0
