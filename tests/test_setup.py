"""The set-up script is idempotent: run again on a set-up machine it skips every step."""
import subprocess


def test_second_setup_run_skips_every_step(workspace_root):
    result = subprocess.run(["bash", str(workspace_root / "scripts" / "setup.sh")],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    for step in ("Debian packages: all present", "Python venv: up to date",
                 "pouchdb-server: up to date", "catkin workspace: up to date"):
        assert any(step in line for line in lines), result.stdout
