"""MCAP (what Foxglove opens): database -> MCAP -> database -> MCAP keeps every message, byte, time
and connection on both backends; the file is what the MCAP reader libraries expect (schemas with
the definition text, channels, summary and indexes for seeking); files of other tools and
unfinished files import with clear answers."""
import io

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros1.decoder import DecoderFactory
from mcap_ros1.writer import Writer as Ros1Writer
from nav_msgs.msg import Odometry
from std_msgs.msg import String
from test_bag import bag_contents, write_bag

from ros_mongo import BagError, open_store, parse_query
from ros_mongo.cli import parse_args, run
from ros_mongo.files.bagio import export_file, import_file, iter_file
from ros_mongo.files.mcapio import McapReader

pytestmark = pytest.mark.db

T0 = 1_700_000_000


def publishers(path):
    return {(topic, header.get("callerid", ""), header.get("latching", "0"))
            for topic, _, _, header in iter_file(path)}


def test_database_to_mcap_to_database_to_mcap_is_lossless(db_server, db_url, tmp_path):
    source, first, second, back = (tmp_path / n for n in ("source.bag", "a.mcap", "b.mcap", "back.bag"))
    write_bag(source)
    with open_store(db_url) as store:
        import_file(source, store, progress=False)
        assert export_file(store, parse_query(""), first, progress=False).messages == 56
        # the MCAP of a bag has the bag's fingerprint: importing it stores nothing twice
        assert import_file(first, store, progress=False).messages == 56
        assert store.count() == 56
    assert bag_contents(first) == bag_contents(source)
    assert publishers(first) == publishers(source)
    with open_store(db_server.database_url(db_url.rsplit("/", 1)[1] + "_copy")) as copy:
        assert import_file(first, copy, progress=False).messages == 56
        latched = [i for i in copy.topics() if i.topic == "/detections"]
        assert latched[0].latching and latched[0].callerid == "/detector"
        export_file(copy, parse_query(""), second, file_format="mcap", compression="zstd", progress=False)
        export_file(copy, parse_query(""), back, progress=False)
    assert bag_contents(second) == bag_contents(first)
    assert publishers(second) == publishers(first)
    assert bag_contents(back) == bag_contents(source)
    assert publishers(back) == publishers(source)


def test_the_mcap_libraries_read_every_channel_schema_and_message_and_can_seek(couchdb_url, tmp_path):
    """What Foxglove needs: ros1 / ros1msg channels with the full definition, a summary with
    statistics and chunk indexes, and messages the schema text alone decodes (mcap_ros1's
    decoder parses the definition with its own genpy copy)."""
    source, exported = tmp_path / "source.bag", tmp_path / "session.mcap"
    write_bag(source)
    with open_store(couchdb_url) as store:
        import_file(source, store, progress=False)
        export_file(store, parse_query(""), exported, compression="lz4", progress=False)
    expected = {}
    for topic, raw, stamp, header in iter_file(source):
        expected.setdefault(topic, []).append((stamp.to_nsec(), raw, header["message_definition"]))
    with open(exported, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros1"
        summary = reader.get_summary()
        assert summary.statistics.message_count == 56 and summary.chunk_indexes
        assert all(index.message_index_offsets for index in summary.chunk_indexes)
        assert {c.topic for c in summary.channels.values()} == set(expected)
        seen = {}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == "ros1" and schema.encoding == "ros1msg"
            assert schema.data.decode() == expected[channel.topic][0][2]
            buffer = io.BytesIO()
            decoded.serialize(buffer)  # the decoded message serializes back to the same bytes
            seen.setdefault(channel.topic, []).append((message.log_time, bytes(message.data),
                                                       buffer.getvalue()))
        assert {t: [(n, raw, raw) for n, raw, _ in v] for t, v in expected.items()} == seen
        # seeking through the chunk indexes: one topic, one time window
        start, end = (T0 + 1) * 10**9, (T0 + 2) * 10**9
        window = [m.log_time for _, _, m in reader.iter_messages(topics=["/scan"], starting_at=start,
                                                                 ending_before=end)]
    assert window == [n for n, _, _ in expected["/scan"] if start <= n < end]
    assert len(window) == 3  # i = 12, 15, 18


def test_mcap_of_another_tool_imports_with_md5sums_from_the_definitions(couchdb_url, tmp_path):
    """mcap_ros1's writer stores no md5sum, callerid or latching; the types are still exact."""
    path = tmp_path / "other.mcap"
    with open(path, "wb") as stream:
        writer = Ros1Writer(stream)
        for i in range(5):
            odom = Odometry()
            odom.pose.pose.position.x = float(i)
            writer.write_message("/odom", odom, log_time=(T0 + i) * 10**9)
            writer.write_message("/chatter", String(data=f"hello {i}"), log_time=(T0 + i) * 10**9 + 1)
        writer.finish()
    with open_store(couchdb_url) as store:
        assert import_file(path, store, progress=False).messages == 10
        infos = {i.topic: i for i in store.topics()}
        assert (infos["/odom"].md5sum, infos["/chatter"].md5sum) == (Odometry._md5sum, String._md5sum)
        xs = [m.fields["pose"]["pose"]["position"]["x"] for m in store.find_messages(topic="/odom")]
        assert xs == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert [m.message().data for m in store.find_messages(topic="/chatter")][-1] == "hello 4"


def _raw_mcap(path, *, foreign=False, count=12):
    """An MCAP of String messages, one chunk each (chunk_size=1); optionally a JSON channel too."""
    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=1, compression=CompressionType.NONE)
        writer.start(profile="ros1", library="test")
        schema = writer.register_schema("std_msgs/String", "ros1msg", String._full_text.encode())
        channel = writer.register_channel("/chatter", "ros1", schema, {"md5sum": String._md5sum})
        if foreign:
            json_schema = writer.register_schema("Point", "jsonschema", b"{}")
            other = writer.register_channel("/json", "json", json_schema)
            writer.add_message(other, T0 * 10**9, b'{"x": 1}', T0 * 10**9)
        for i in range(count):
            buffer = io.BytesIO()
            String(data=f"message {i:03d}").serialize(buffer)
            writer.add_message(channel, (T0 + i) * 10**9, buffer.getvalue(), (T0 + i) * 10**9, i)
        writer.finish()


def test_an_unfinished_mcap_recovers_its_complete_chunks(tmp_path):
    intact, cut = tmp_path / "intact.mcap", tmp_path / "cut.mcap"
    _raw_mcap(intact)
    with open(intact, "rb") as stream:
        chunks = sorted(make_reader(stream).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) == 12  # one message per chunk
    end = chunks[7].chunk_start_offset + 20  # inside the eighth chunk; no summary, no footer
    cut.write_bytes(intact.read_bytes()[:end])
    with McapReader(cut) as reader:
        assert reader.count() == 7
        texts = [String().deserialize(m.data).data for m in reader.messages()]
        assert reader.recovery.messages == 7 and reader.recovery.topics == 1
        assert reader.recovery.skipped_bytes == end - chunks[7].chunk_start_offset
    assert texts == [f"message {i:03d}" for i in range(7)]
    with McapReader(intact) as reader:
        assert reader.recovery is None and reader.count() == 12


def test_mcap_errors_are_clear(couchdb_url, tmp_path, capsys):
    mixed = tmp_path / "mixed.mcap"
    _raw_mcap(mixed, foreign=True, count=3)
    with open_store(couchdb_url) as store:
        with pytest.raises(BagError, match=r"channel /json holds json / jsonschema, not ROS 1"):
            import_file(mixed, store, progress=False)
        assert import_file(mixed, store, topics=["/chatter"], progress=False).messages == 3
        with pytest.raises(BagError, match="mcap compression must be one of"):
            export_file(store, parse_query(""), tmp_path / "x.mcap", compression="bz2", progress=False)
        with pytest.raises(BagError, match="neither a ROS bag nor an MCAP file"):
            (tmp_path / "notes.txt").write_text("hello")
            import_file(tmp_path / "notes.txt", store, progress=False)
    out = tmp_path / "chatter.data"
    arguments = parse_args(["--no-progress", "--db-url", couchdb_url, "export", str(out), "--format", "mcap"])
    run(arguments)  # the command line's export (its "ERROR: ..." lines: test_bag.py)
    assert "3 messages" in capsys.readouterr().out
    assert out.read_bytes().startswith(b"\x89MCAP0\r\n")
    with pytest.raises(BagError, match=r"bag .*chatter.data exists"):
        run(arguments)
    assert not (tmp_path / "chatter.data.partial").exists()


def test_an_empty_export_is_a_valid_mcap_file(couchdb_url, tmp_path):
    """An export that matches nothing is still a valid MCAP file that imports as empty."""
    path = tmp_path / "empty.mcap"
    with open_store(couchdb_url) as store:
        assert export_file(store, parse_query("topic /nothing"), path, progress=False).messages == 0
        assert import_file(path, store, progress=False).messages == 0
    with open(path, "rb") as stream:
        assert make_reader(stream).get_summary().statistics.message_count == 0
