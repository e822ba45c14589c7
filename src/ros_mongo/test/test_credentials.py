"""Credentials never show: redaction of every URL form, passwords from a file or the environment,
errors and command lines without them (real servers and the real roslaunch / CLI tools)."""
import os
import subprocess
import sys

import pytest

from ros_mongo import StoreError, open_store
from ros_mongo.urls import (
    PASSWORD_ENV,
    USER_ENV,
    CredentialsError,
    check_url,
    password_in_url,
    redact_url,
    scrub,
    split_credentials,
    with_credentials,
)

SECRET = "S3cr3t-pw"


@pytest.mark.parametrize("url, kept", [
    (f"mongodb://robot:{SECRET}@h1:27017,h2:27017/robot_data?replicaSet=rs&authSource=admin",
     ["mongodb://robot:***@h1:27017,h2:27017/robot_data", "replicaSet=rs", "authSource=admin"]),
    (f"http://admin:{SECRET}@db.example.org:5984/robot_data", ["http://admin:***@db.example.org:5984/robot_data"]),
    (f"https://robot:{SECRET}@host/couchdb/robot_data", ["https://robot:***@host/couchdb/robot_data"]),
    (f"mongodb://h/db?authSource=admin&password={SECRET}&token={SECRET}x&w=majority",
     ["authSource=admin", "password=***", "token=***", "w=majority"]),
    (f"mongodb+srv://u:{SECRET}@cluster.example.net/db?authMechanism=MONGODB-AWS"
     f"&authMechanismProperties=AWS_SESSION_TOKEN:{SECRET}", ["authMechanism=MONGODB-AWS"]),
    (f"mongodb://robot:{SECRET}@with@at@h:27017/db", ["mongodb://robot:***@h:27017/db"]),
    (f"robot:{SECRET}@127.0.0.1:27017/db", ["robot:***@127.0.0.1:27017/db"]),
    (f"mongodb://robot:{SECRET}@h/db#frag", ["#frag"]),
    ("mongodb://h1:27017,h2:27017/db?replicaSet=rs", ["mongodb://h1:27017,h2:27017/db?replicaSet=rs"]),
])
def test_redaction_hides_secrets_and_keeps_the_rest(url, kept):
    shown = redact_url(url)
    assert SECRET not in shown
    for part in kept:
        assert part in shown
    assert password_in_url(url) == (SECRET in url)


def test_redaction_never_raises():
    for odd in [None, 42, "", "://", "@", "mongodb://@/", "mongodb://:@h", "a" * 10000, "mongodb://[::1]:27017/db"]:
        assert isinstance(redact_url(odd), str)


def test_a_url_without_scheme_is_refused_without_echoing_the_password():
    with pytest.raises(StoreError) as err:
        open_store(f"robot:{SECRET}@127.0.0.1:27017/robot_data")
    assert SECRET not in str(err.value) and "robot:***@127.0.0.1:27017" in str(err.value)
    with pytest.raises(StoreError) as err:
        check_url(f"{SECRET}")
    assert "database URL must look like" in str(err.value)


def test_an_authenticated_replica_set_url_opens_and_shows_redacted():
    url = f"mongodb://robot:{SECRET}@127.0.0.1:1,127.0.0.1:2/robot_data?replicaSet=rs&serverSelectionTimeoutMS=300"
    store = open_store(url, connect=False)
    try:
        assert SECRET not in store.url and SECRET not in repr(store)
        with pytest.raises(StoreError) as err:
            store.count()
        assert SECRET not in str(err.value)
    finally:
        store.close()


def test_password_from_file_or_environment(tmp_path):
    base = "mongodb://robot@db:27017/robot_data?authSource=admin"
    file = tmp_path / "creds"
    file.write_text(f"# robot account\n{SECRET}\n")
    assert with_credentials(base, credentials_file=str(file), environ={}) == \
        f"mongodb://robot:{SECRET}@db:27017/robot_data?authSource=admin"
    file.write_text("reader:p@ss:word/x\n")
    assert with_credentials(base, credentials_file=str(file), environ={}) == \
        "mongodb://reader:p%40ss%3Aword%2Fx@db:27017/robot_data?authSource=admin"
    assert with_credentials("http://db:5984/robot_data", environ={PASSWORD_ENV: SECRET, USER_ENV: "rob"}) == \
        f"http://rob:{SECRET}@db:5984/robot_data"
    assert with_credentials("http://db:5984/robot_data", environ={}) == "http://db:5984/robot_data"
    # the file wins over the environment; a password in the URL wins over both
    file.write_text("fromfile\n")
    assert ":fromfile@" in with_credentials(base, credentials_file=str(file), environ={PASSWORD_ENV: "env"})
    assert with_credentials("http://u:inurl@db/x", credentials_file=str(file), environ={}) == "http://u:inurl@db/x"


def test_bad_credentials_are_clear_and_never_quote_the_secret(tmp_path):
    with pytest.raises(CredentialsError, match="cannot read the database credentials file .*missing"):
        with_credentials("http://u@db/x", credentials_file=str(tmp_path / "missing"), environ={})
    two = tmp_path / "two"
    two.write_text(f"u:{SECRET}\nsecond{SECRET}\n")
    with pytest.raises(CredentialsError, match="must hold one line") as err:
        with_credentials("http://u@db/x", credentials_file=str(two), environ={})
    assert SECRET not in str(err.value)
    with pytest.raises(CredentialsError, match="no user") as err:
        with_credentials("http://db/x", environ={PASSWORD_ENV: SECRET})
    assert SECRET not in str(err.value)


def test_scrub_removes_the_password_from_driver_messages():
    url = f"mongodb://robot:{SECRET.replace('-', '%2D')}@h/db"
    text = f"auth failed for {SECRET} at mongodb://robot:{SECRET}@h/db and {SECRET.replace('-', '%2D')}"
    assert SECRET not in scrub(text, url) and "%2D" not in scrub(text, url)


@pytest.mark.db
def test_the_cli_takes_the_password_from_a_file_and_never_shows_it(mongodb_url, tmp_path):
    """nx-27017 has no accounts: the driver's attempt to log in fails, so the error path is real."""
    creds = tmp_path / "creds"
    creds.write_text(f"robot:{SECRET}\n")
    cli = [sys.executable, "-c", "import sys; from ros_mongo.cli import main; sys.exit(main())"]
    run = subprocess.run(cli + ["info", "--db-url", mongodb_url + "?serverSelectionTimeoutMS=3000",
                                "--db-credentials-file", str(creds)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and run.stderr.startswith("ERROR: "), run.stderr
    assert "robot:***@" in run.stderr and SECRET not in run.stdout + run.stderr
    # the same from the environment, and a warning (redacted) when the URL carries the password
    env = dict(os.environ, **{PASSWORD_ENV: SECRET, USER_ENV: "robot"})
    run = subprocess.run(cli + ["info", "--db-url", mongodb_url], capture_output=True, text=True, timeout=120,
                         env=env)
    assert run.returncode == 1 and SECRET not in run.stdout + run.stderr
    host_url = mongodb_url.replace("mongodb://", f"mongodb://robot:{SECRET}@")
    run = subprocess.run(cli + ["info", "--db-url", host_url], capture_output=True, text=True, timeout=120)
    assert "WARNING: the database URL" in run.stderr and SECRET not in run.stdout + run.stderr


def test_bag_converter_never_puts_the_url_on_the_command_line(tmp_path):
    """roslaunch's own --args prints the node's command line as roslaunch would run it."""
    run = subprocess.run(["roslaunch", "--args", "/ros_mongo_bag_import", "ros_mongo", "bag_converter.launch",
                          f"bag:={tmp_path / 'x.bag'}", "db_url:=mongodb://robot@db:27017/robot_data",
                          f"db_credentials_file:={tmp_path / 'creds'}"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    env_part, _, argv = run.stdout.strip().partition("/ros_mongo_bag ")
    assert "ROS_MONGO_DB_URL=" in env_part and argv
    assert "--db-url" not in argv and "mongodb://" not in argv
    assert f"--db-credentials-file {tmp_path / 'creds'}" in argv


def test_one_parser_reads_the_userinfo_up_to_the_last_at_and_decodes_it():
    """Every CouchDB request goes through one client and one parser: a raw password holding '@',
    '/' and ':' ends at the last '@' before the path; a percent-encoded one is decoded."""
    from ros_mongo.fleet.replication import CouchDatabase
    from ros_mongo.storage.couch_client import CouchClient

    raw = "http://robot:a@b/c:d@db.example:5984/proxy/fleet"
    assert split_credentials(raw) == ("http://db.example:5984/proxy/fleet", ("robot", "a@b/c:d"))
    encoded = "https://robot:a%40b%2Fc%3Ad%25@db.example/fleet"
    assert split_credentials(encoded)[1] == ("robot", "a@b/c:d%")
    for client in (CouchClient(raw), CouchDatabase(raw)):
        assert (client.server_url, client.name, client.auth) == \
            ("http://db.example:5984/proxy", "fleet", ("robot", "a@b/c:d"))
        assert "a@b/c:d" not in client.shown and "robot:***@" in client.shown
