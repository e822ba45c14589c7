"""`ros_mongo_bag`: bags into the database and back, with a progress bar.

    ros_mongo_bag import run1.bag run2.bag --db-url http://127.0.0.1:5984/robot_data --tags lab
    ros_mongo_bag export out.bag --db-url mongodb://127.0.0.1:27017/robot_data --query "tags lidar"
    ros_mongo_bag info --db-url http://127.0.0.1:5984/robot_data

Exits 0 on success, 1 with one "ERROR: ..." line otherwise.
"""
import argparse
import re
import sys
from typing import List, Optional

from ros_mongo.bagio import export_bag, import_bag
from ros_mongo.errors import StoreError
from ros_mongo.query import parse_query, query_from_mapping
from ros_mongo.store import open_store

__all__ = ["main"]

DEFAULT_URL = "http://127.0.0.1:5984/robot_data"


def parse_args(argv: List[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="ros_mongo_bag", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.splitlines()[1:]))
    parser.add_argument("--db-url", default=DEFAULT_URL, help=f"database URL (default {DEFAULT_URL})")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    commands = parser.add_subparsers(dest="command", required=True)
    up = commands.add_parser("import", help="store the messages of bags")
    up.add_argument("bags", nargs="+", help="bag files")
    up.add_argument("--topics", nargs="*", help="only these topics")
    up.add_argument("--tags", nargs="*", default=[], help="tags for every message")
    up.add_argument("--session-id", help="session id (default: the bag's file name)")
    up.add_argument("--robot-id", help="robot id")
    down = commands.add_parser("export", help="write stored messages to a new bag")
    down.add_argument("bag", help="the bag to write (refuses to overwrite without --force)")
    down.add_argument("--query", default="", help='YAML/JSON query or "<key> <value>" ("tags lidar")')
    down.add_argument("--topics", nargs="*", help="only these topics")
    down.add_argument("--tags", nargs="*", help="only messages with all these tags")
    down.add_argument("--session-id", help="only this session")
    down.add_argument("--start-time", type=float, help="receive time from (s)")
    down.add_argument("--end-time", type=float, help="receive time until (s)")
    down.add_argument("--compression", choices=["none", "bz2", "lz4"], default="none")
    down.add_argument("--force", action="store_true", help="overwrite an existing bag")
    commands.add_parser("info", help="stored topics and message counts")
    for sub in commands.choices.values():  # options work before or after the command
        sub.add_argument("--db-url", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        sub.add_argument("--no-progress", action="store_true", default=argparse.SUPPRESS,
                         help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def _export_query(args: argparse.Namespace):
    query = parse_query(args.query)
    mapping = {"topics": args.topics or query.topics, "tags": args.tags or query.tags,
               "type": query.msg_type, "session_id": args.session_id or query.session_id,
               "robot_id": query.robot_id, "fields": query.fields or None,
               "start_time": args.start_time if args.start_time is not None else query.start_time,
               "end_time": args.end_time if args.end_time is not None else query.end_time}
    return query_from_mapping(mapping)


def run(args: argparse.Namespace) -> None:
    progress = not args.no_progress
    with open_store(args.db_url) as store:
        if args.command == "import":
            for bag in args.bags:
                result = import_bag(bag, store, topics=args.topics, tags=args.tags,
                                    session_id=args.session_id, robot_id=args.robot_id, progress=progress)
                print(f"{bag}: {result.messages} messages, {result.bytes / 1e6:.1f} MB in "
                      f"{result.seconds:.1f} s ({result.rate:.0f} msg/s, {result.megabytes_per_second:.1f} "
                      f"MB/s) into {store.url}")
        elif args.command == "export":
            query = _export_query(args)
            result = export_bag(store, query, args.bag, overwrite=args.force,
                                compression=args.compression, progress=progress)
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
    try:
        run(args)
    except StoreError as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("ERROR: interrupted", file=sys.stderr)
        return 1
    return 0
