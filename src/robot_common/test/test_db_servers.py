"""The local database servers' command lines (the one place they are written)."""
import pytest

from robot_common.db_servers import couchdb_server_command, mongodb_server_command, server_command


def test_local_server_command_lines(tmp_path, monkeypatch):
    monkeypatch.setenv("POUCHDB_SERVER_BIN", str(tmp_path / "pouchdb-server"))
    monkeypatch.setenv("NX27017_BIN", str(tmp_path / "nx-27017"))
    with pytest.raises(FileNotFoundError, match="pouchdb-server not found: set POUCHDB_SERVER_BIN"):
        couchdb_server_command(port=5984, data_dir=tmp_path)
    (tmp_path / "pouchdb-server").touch()
    (tmp_path / "nx-27017").touch()
    couch = couchdb_server_command(port=6000, data_dir=tmp_path / "db", in_memory=True)
    assert couch[:3] == ["node", "--unhandled-rejections=warn", str(tmp_path / "pouchdb-server")]
    assert couch[3:] == ["-o", "127.0.0.1", "-p", "6000", "-d", str(tmp_path / "db"),
                         "-c", str(tmp_path / "db" / "config.json"), "-n", "-m"]
    assert server_command("couchdb", "0.0.0.0", 6000, tmp_path)[-1] == "-n"  # kept on disk
    mongo = mongodb_server_command(port=7000, data_dir=tmp_path / "db")
    assert mongo == [str(tmp_path / "nx-27017"), "--data-dir", str(tmp_path / "db"), "--host", "127.0.0.1",
                     "-p", "7000", "--pid-file", str(tmp_path / "db" / "nx-27017.pid"),
                     "--log-file", str(tmp_path / "db" / "nx-27017.log")]
    memory = mongodb_server_command(port=7000, data_dir=None, in_memory=True, pid_file=tmp_path / "a.pid")
    assert memory[1:3] == ["--data-dir", "memory"] and memory[-1] == str(tmp_path / "a.log")
    with pytest.raises(ValueError, match="pid_file of its own"):
        mongodb_server_command(port=7000, data_dir=None, in_memory=True)
