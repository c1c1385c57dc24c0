"""``./run``'s set-up waits for another package manager's lock, saying so, instead of failing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
WAIT = REPO / "tools" / "wait_for_apt.sh"

HOLD = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)
fcntl.lockf(fd, fcntl.LOCK_EX)          # the kind of lock apt and dpkg take
print("held", flush=True)
time.sleep(float(sys.argv[2]))
"""


@pytest.mark.skipif(os.geteuid() != 0 and not Path("/usr/bin/sudo").exists(), reason="needs root or sudo")
def test_waits_for_a_held_dpkg_lock_with_a_message(tmp_path: Path) -> None:
    lock = tmp_path / "lock-frontend"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock), "3"], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    env = {**os.environ, "HUEFRINGE_APT_LOCKS": f"{tmp_path / 'absent'} {lock}"}
    proc = subprocess.run(["bash", str(WAIT), "60"], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert holder.poll() is not None  # it returned only after the other package manager let go
    assert f"another package manager holds {lock} (apt, dpkg or automatic updates); waiting for it" in proc.stderr
    assert "the package manager finished after about" in proc.stderr
    # the lock free: no message, no wait
    quiet = subprocess.run(["bash", str(WAIT), "60"], env=env, capture_output=True, text=True)
    assert quiet.returncode == 0 and quiet.stderr == ""


def test_gives_up_after_its_timeout_naming_the_lock(tmp_path: Path) -> None:
    lock = tmp_path / "lock"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock), "30"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        env = {**os.environ, "HUEFRINGE_APT_LOCKS": str(lock)}
        proc = subprocess.run(["bash", str(WAIT), "0"], env=env, capture_output=True, text=True)
        assert proc.returncode == 1
        assert f"{lock} is still held after 0 s: let the other package manager finish" in proc.stderr
    finally:
        holder.kill()
        holder.wait()


def test_bootstrap_waits_before_apt_get() -> None:
    text = (REPO / "tools" / "bootstrap.sh").read_text()
    assert text.index('"$here/tools/wait_for_apt.sh"') < text.index("apt-get -o DPkg::Lock::Timeout=1800 update")
