#!/usr/bin/env bash
# Idempotent set-up of everything huefringe needs on a Debian machine with Python >= 3.11:
# Debian libraries (Open3D needs libusb; off-screen VTK needs GL/EGL/OSMesa; the HTML report
# test needs chromium), then a project virtualenv with the pinned stack, installed with uv.
# A stamp keyed on the inputs makes a repeated call cost a few milliseconds.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$here/.venv"
stamp="$venv/.huefringe-stamp"
apt_pkgs=(libusb-1.0-0 libgl1 libegl1 libosmesa6 libgomp1 chromium fonts-dejavu-core)

key="$(cat "$here/pyproject.toml" "$here/tools/bootstrap.sh" "$here/tools/wait_for_apt.sh" | sha256sum | cut -c1-16)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$key" ]; then
  exit 0
fi

log() { printf '[bootstrap] %s\n' "$*" >&2; }

missing=()
for p in "${apt_pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  log "installing Debian packages: ${missing[*]}"
  # another apt or dpkg (automatic updates) may hold the lock: wait for it, saying so, rather than fail
  "$here/tools/wait_for_apt.sh"
  $sudo apt-get -o DPkg::Lock::Timeout=1800 update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get -o DPkg::Lock::Timeout=1800 install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
fi

py="$(command -v python3.11 || command -v python3)"
"$py" -c 'import sys; assert sys.version_info >= (3, 11), "huefringe needs Python >= 3.11"'
if [ ! -x "$venv/bin/python" ]; then
  log "creating virtualenv $venv"
  "$py" -m venv "$venv"
fi
if [ ! -x "$venv/bin/uv" ]; then
  log "installing uv"
  "$venv/bin/python" -m pip install -q --disable-pip-version-check "uv>=0.4,<1"
fi
log "installing huefringe and its pinned dependencies"
VIRTUAL_ENV="$venv" "$venv/bin/uv" pip install -q --python "$venv/bin/python" --compile-bytecode -e "$here[test,docs]"
echo "$key" > "$stamp"
log "done"
