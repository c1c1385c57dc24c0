#!/usr/bin/env bash
# Wait until no other package manager (apt, dpkg, unattended-upgrades, a software centre) holds
# Debian's locks, saying so once, instead of failing on "Could not get lock". dpkg and apt take
# POSIX (fcntl) locks, so the probe takes and drops the same kind of lock, without waiting.
#   tools/wait_for_apt.sh [TIMEOUT_SECONDS]       (default 1800; HUEFRINGE_APT_LOCKS overrides the lock files)
set -euo pipefail
timeout="${1:-1800}"
read -r -a locks <<< "${HUEFRINGE_APT_LOCKS:-/var/lib/dpkg/lock-frontend /var/lib/dpkg/lock /var/lib/apt/lists/lock /var/cache/apt/archives/lock}"
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
py="$(command -v python3)"

held() {  # prints the first lock file another process holds
  $sudo "$py" - "${locks[@]}" <<'PY'
import fcntl, os, sys
for path in sys.argv[1:]:
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        continue  # absent (never used) or unreadable: nothing to wait for
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        print(path)
        break
    finally:
        os.close(fd)
PY
}

waited=0
while lock="$(held)" && [ -n "$lock" ]; do
  if [ "$waited" -eq 0 ]; then
    printf '[bootstrap] another package manager holds %s (apt, dpkg or automatic updates); waiting for it to finish (up to %s s) ...\n' "$lock" "$timeout" >&2
  fi
  if [ "$waited" -ge "$timeout" ]; then
    printf '[bootstrap] %s is still held after %s s: let the other package manager finish (or stop it), then run ./run again\n' "$lock" "$timeout" >&2
    exit 1
  fi
  sleep 2
  waited=$((waited + 2))
done
if [ "$waited" -gt 0 ]; then
  printf '[bootstrap] the package manager finished after about %s s; continuing\n' "$waited" >&2
fi
