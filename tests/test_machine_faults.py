"""Faults of the machine met for real, not injected: a disk that fills (a small tmpfs) and a
read-only one, under ``unshare -m`` (root with mount rights, as CI's container has them;
skipped elsewhere), and outputs that are a user's file or a link to one. Each is one line
and exit status 2, the user's file intact, and the rerun on a freed disk finishes."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow  # real commands, several seconds each

PYTHON = sys.executable


def _mounted(tmp_path, script: str) -> subprocess.CompletedProcess:
    """``script`` (bash) in a mount namespace of its own, ``$DISK`` a tmpfs it may mount."""
    if shutil.which("unshare") is None:
        pytest.skip("no unshare here")
    disk = tmp_path / "disk"
    disk.mkdir()
    probe = subprocess.run(["unshare", "-m", "mount", "-t", "tmpfs", "tmpfs", str(disk)],
                           capture_output=True)  # fmt: skip
    if probe.returncode != 0:
        pytest.skip("no right to mount a tmpfs here")
    env = {**os.environ, "DISK": str(disk), "PY": PYTHON}
    return subprocess.run(["unshare", "-m", "bash", "-c", f"set -u\n{script}"], env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def _lines(text: str) -> dict[str, str]:
    return dict(line.split("=", 1) for line in text.splitlines() if "=" in line)


@pytest.mark.parametrize(
    "command,size",
    [
        ("$PY -m bgap.simulate backend=vector env=dense episodes=3 env.duration=20 out=o", "60k"),
        ("$PY -m bgap.train profile=tiny run_dir=o", "100k"),
    ],
    ids=["simulate", "train"],
)
def test_a_disk_that_fills_is_one_line_and_the_rerun_finishes(command, size, tmp_path):
    done = _mounted(tmp_path, f"""
mount -t tmpfs -o size={size} tmpfs "$DISK" && cd "$DISK"
{command} > /dev/null 2> first.err; echo "first=$?"
echo "said=$(tail -1 first.err)"; echo "lines=$(grep -vc '%|\\|━' first.err)"
mount -o remount,size=200m "$DISK"
{command} > /dev/null 2> again.err; echo "again=$?"
""")  # fmt: skip
    seen = _lines(done.stdout)
    assert seen.get("first") == "2", done.stdout + done.stderr
    assert seen["said"].startswith("bgap.") and "no space left on the device" in seen["said"]
    assert "run the same command again" in seen["said"] and seen["lines"] == "1", done.stdout
    assert seen.get("again") == "0", done.stdout


def test_a_read_only_disk_is_one_line(tmp_path):
    done = _mounted(
        tmp_path,
        """
mount -t tmpfs -o ro tmpfs "$DISK" && cd "$DISK"
$PY -m bgap.simulate backend=vector episodes=1 env.duration=2 out=o > /dev/null 2> /tmp/ro.err
echo "status=$?"; echo "said=$(tail -1 /tmp/ro.err)"; echo "lines=$(wc -l < /tmp/ro.err)"
""",
    )
    seen = _lines(done.stdout)
    assert seen.get("status") == "2", done.stdout + done.stderr
    assert "is on a read-only file system" in seen["said"] and seen["lines"] == "1"


@pytest.mark.parametrize("out", ["notes.txt", "link"])
def test_an_output_that_is_a_users_file_or_a_link_to_one(out, tmp_path):
    (tmp_path / "notes.txt").write_text("mine\n")
    (tmp_path / "link").symlink_to(tmp_path / "notes.txt")
    args = ["-m", "bgap.simulate", "backend=vector", "episodes=1", "env.duration=2", f"out={out}"]
    done = subprocess.run([PYTHON, *args], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "is a file, not a folder" in done.stderr
    assert (tmp_path / "notes.txt").read_text() == "mine\n" and (tmp_path / "link").is_symlink()
