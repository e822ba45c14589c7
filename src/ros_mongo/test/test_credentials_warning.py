"""A password in a database URL is warned about once, at start, without the password, pointing to
the credentials file: in the library and in a real node started by roslaunch (its log lines,
rosout, diagnostics and command line never show the password)."""
import logging
import uuid
import xmlrpc.client
from pathlib import Path

import pytest
from recorder_harness import start_recorder

from ros_harness import wait_until
from ros_mongo import open_store
from ros_mongo.urls import password_warning, with_credentials

SECRET = "Pw-" + uuid.uuid4().hex[:12]
WARNING_LOGGER = "rosout.ros_mongo"


def _url(host="db.example.org", secret=SECRET):
    return f"http://robot:{secret}@{host}:5984/robot_data_{uuid.uuid4().hex[:6]}"


def test_the_warning_comes_once_per_url_and_never_holds_the_password():
    url = _url()
    first = password_warning(url)
    assert first is not None and SECRET not in first and SECRET[:4] not in first
    assert "robot:***@db.example.org" in first and "~db_credentials_file" in first
    assert password_warning(url) is None  # once per process and URL
    assert password_warning(_url()) is not None  # another URL gets its own
    assert password_warning("http://robot@db.example.org:5984/robot_data") is None
    query_secret = f"mongodb://h/db?authSource=admin&password={SECRET}"
    assert SECRET not in (password_warning(query_secret) or "x" + SECRET)


def test_only_a_password_in_the_given_url_is_warned_about(caplog, tmp_path):
    creds = tmp_path / "creds"
    creds.write_text(f"robot:{SECRET}\n")
    with caplog.at_level(logging.WARNING, logger=WARNING_LOGGER):
        completed = with_credentials(_url().replace(f":{SECRET}@", "@"), credentials_file=str(creds),
                                     environ={})
        assert SECRET in completed  # the connection URL has it ...
        with_credentials(completed.replace("db.example", "db2.example"), environ={}, warn=False)
        assert caplog.records == []  # ... but nobody wrote it into a parameter
        url = _url()
        with_credentials(url, environ={})
        with_credentials(url, environ={})
    assert len(caplog.records) == 1 and caplog.records[0].levelno == logging.WARNING
    assert SECRET not in caplog.text and "carries a password" in caplog.text


@pytest.mark.db
@pytest.mark.parametrize("couch_server", ["pouchdb"], indirect=True)  # the URL's own password only
def test_a_reopened_store_does_not_warn_again(couchdb_url, caplog, tmp_path):
    """The replay loader reopens the store in another process with `reopen_args()`: its URL holds
    the password this process added, which must not look like a password given in a parameter."""
    creds = tmp_path / "creds"
    creds.write_text(f"robot:{SECRET}\n")
    with caplog.at_level(logging.WARNING, logger=WARNING_LOGGER):
        with open_store(couchdb_url, connect=False, credentials_file=str(creds)) as store:
            url, options = store.reopen_args()
        assert SECRET in url
        with open_store(url, connect=False, **options):
            pass
    assert caplog.records == []


def _lines_with(text, path: Path):
    return [line for line in path.read_text(errors="replace").splitlines() if text in line]


@pytest.mark.ros
@pytest.mark.db
@pytest.mark.parametrize("couch_server", ["pouchdb"], indirect=True)  # the URL's own password only
def test_a_node_started_by_roslaunch_warns_once_and_never_shows_the_password(roslaunch, couchdb_url,
                                                                            rospy_node, roscore, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Log

    url = couchdb_url.replace("http://", f"http://robot:{SECRET}@")
    logs, reports = [], []
    rosout = rospy_node.Subscriber("/rosout_agg", Log, logs.append)
    everything = rospy_node.Subscriber("/diagnostics", DiagnosticArray, lambda m: reports.append(repr(m)))
    try:
        launch = start_recorder(roslaunch, url, tmp_path)
        wait_until(lambda: len(reports) >= 3, 90, what="three diagnostics reports")
        screen = launch.process.log_path
        wait_until(lambda: _lines_with("carries a password", screen), 60, what="the warning on the screen")
        node_logs = list(Path(roscore.log_dir).rglob(f"{launch.node_name.strip('/')}*.log"))
        assert node_logs, "the node's log file"
        wait_until(lambda: any(_lines_with("carries a password", p) for p in node_logs), 60,
                   what="the warning in the node's log file")
        warnings = _lines_with("carries a password", screen)
        assert len(warnings) == 1 and "robot:***@" in warnings[0] and "db_credentials_file" in warnings[0]
        # roslaunch's own parameter summary shows the start of every value (what the warning is
        # about); no other line does, from roslaunch or the node
        leaks = [line for line in _lines_with(SECRET[:4], screen) if not line.startswith(" * /")]
        assert leaks == []
        assert all(not _lines_with(SECRET[:4], path) for path in node_logs)
        assert all(SECRET[:4] not in (m.msg + m.name) for m in logs)
        assert reports and all(SECRET[:4] not in report for report in reports)  # hardware_id too
        assert "robot:***@" in "".join(reports)
        pid = _node_pid(launch.node_name)
        command_line = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
        assert launch.node_name.strip("/") in command_line and SECRET[:4] not in command_line
    finally:
        rosout.unregister()
        everything.unregister()


def _node_pid(node_name):
    import rosgraph

    uri = rosgraph.Master("/pytest_pid").lookupNode(node_name)
    code, _message, pid = xmlrpc.client.ServerProxy(uri).getPid("/pytest_pid")
    assert code == 1
    return pid
