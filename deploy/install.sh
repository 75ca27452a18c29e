#!/usr/bin/env bash
# radar-edge installer for Raspberry Pi OS bookworm (64-bit) -- idempotent; run it again to update.
#
# What it does (each step reports "installed", "updated", "unchanged" or "skipped: why"):
#   1. system packages (python3-venv, can-utils, iproute2, ...) and the C toolchain
#      that builds the compiled kernels (build-essential, python3-dev)               [apt-get]
#   2. service user `radar-edge` (system user, member of `dialout`)                  [useradd]
#   3. virtual environment /opt/radar-edge/venv with the radar-edge package, its
#      kernels (edge/native) compiled here; says whether they load                   [pip]
#   4. /etc/radar-edge/radar-edge.toml from the commented example (never overwritten;
#      the shipped example is always refreshed as radar-edge.example.toml)
#   5. udev rule: Distance2Go (USB 058B:0058) -> /dev/radar-d2g, group dialout, mode 0660,
#      ignored by ModemManager (which would otherwise probe it with AT commands)
#   6. HAT: config.txt overlays (MCP2515 CAN, PL011 UART for RS-485), serial console off,
#      can0 at 500 kbit/s with restart-ms and txqueuelen via systemd-networkd
#   7. systemd unit radar-edge.service (enabled; started with --start)
#
# Testable: --root DIR lays every file out under DIR and runs no system command (apt, useradd,
# pip, systemctl, udevadm are listed as skipped); --dry-run changes nothing and prints each action.
set -euo pipefail

PROG=$(basename "$0")
HERE=$(cd "$(dirname "$0")" && pwd)
SRC_DIR=$(cd "$HERE/.." && pwd)

ROOT=/
DRY_RUN=0
UNINSTALL=0
PURGE=0
DO_APT=1
DO_HAT=auto
DO_START=0
PREFIX=/opt/radar-edge
SVC_USER=radar-edge
WHEELS=""
PKG_SPEC=""
CAN_OSC=12000000
CAN_INT=25
CAN_BITRATE=500000
CAN_RESTART_MS=100
CAN_TXQUEUELEN=1024
PYTHON=python3

usage() {
  cat <<EOF
usage: $PROG [options]

Installs radar-edge as a systemd service on a Raspberry Pi (Raspberry Pi OS bookworm, 64-bit) with a
Distance2Go on USB and an MCP2515 CAN + RS-485 HAT. Idempotent: run it again after an update.

options:
  --root DIR           install the files under DIR instead of / and run no system command
                       (for tests and image building); default /
  --dry-run            print what would be done, change nothing
  --uninstall          remove the service, udev rule, network files, HAT block and the venv;
                       keeps /etc/radar-edge and the recordings in /var/lib/radar-edge
  --purge              with --uninstall: also remove /etc/radar-edge, /var/lib/radar-edge, the user
  --wheels DIR         install the package from the wheels in DIR, offline (pip --no-index)
  --package SPEC       pip requirement or path to install (default: this source tree, $SRC_DIR)
  --prefix DIR         where the venv lives (default $PREFIX)
  --no-apt             do not install system packages
  --hat / --no-hat     set up the CAN + RS-485 HAT (default: only when config.txt exists)
  --can-oscillator HZ  MCP2515 crystal (default $CAN_OSC: Waveshare RS485 CAN HAT; many boards use 16000000)
  --can-interrupt GPIO MCP2515 interrupt pin (default $CAN_INT)
  --can-bitrate BPS    can0 bitrate (default $CAN_BITRATE)
  --start              start (or restart) the service at the end
  -h, --help           this help

examples:
  sudo deploy/install.sh                            # from a checkout, on the Pi
  sudo deploy/install.sh --wheels ./wheels --start  # offline, from downloaded wheels
  deploy/install.sh --root /tmp/img --no-apt        # lay the files out in /tmp/img (no root needed)
  sudo deploy/install.sh --dry-run                  # show every step, change nothing
  sudo deploy/install.sh --uninstall                # remove (keeps config and recordings)

after installing:
  sudo reboot                                       # when the HAT overlays were added
  radar-edge doctor --config /etc/radar-edge/radar-edge.toml
  systemctl status radar-edge; journalctl -u radar-edge -f
EOF
}

die() { echo "$PROG: error: $*" >&2; exit 2; }

while [ $# -gt 0 ]; do
  case "$1" in
    --root) ROOT=${2:?--root needs a directory}; shift ;;
    --root=*) ROOT=${1#*=} ;;
    --dry-run) DRY_RUN=1 ;;
    --uninstall) UNINSTALL=1 ;;
    --purge) PURGE=1 ;;
    --wheels) WHEELS=${2:?--wheels needs a directory}; shift ;;
    --package) PKG_SPEC=${2:?--package needs a value}; shift ;;
    --prefix) PREFIX=${2:?--prefix needs a directory}; shift ;;
    --no-apt) DO_APT=0 ;;
    --hat) DO_HAT=1 ;;
    --no-hat) DO_HAT=0 ;;
    --can-oscillator) CAN_OSC=${2:?}; shift ;;
    --can-interrupt) CAN_INT=${2:?}; shift ;;
    --can-bitrate) CAN_BITRATE=${2:?}; shift ;;
    --start) DO_START=1 ;;
    -h|--help) usage; exit 0 ;;
    *) usage >&2; die "unknown option: $1" ;;
  esac
  shift
done

[ "$PURGE" = 1 ] && [ "$UNINSTALL" = 0 ] && die "--purge only goes with --uninstall"
mkdir -p -- "$ROOT" 2>/dev/null || [ "$DRY_RUN" = 1 ] || die "cannot create $ROOT"
ROOT=$(cd "$ROOT" 2>/dev/null && pwd || echo "$ROOT")
[ "$ROOT" = "/" ] && ROOT=""
SYSTEM=0; [ -z "$ROOT" ] && SYSTEM=1   # run system commands only when installing into the real /
if [ "$SYSTEM" = 1 ] && [ "$DRY_RUN" = 0 ] && [ "$(id -u)" != 0 ]; then
  die "run as root (sudo $0 ...), or use --root DIR / --dry-run"
fi

MARK_BEGIN="# >>> radar-edge HAT (managed by deploy/install.sh; edit outside this block) >>>"
MARK_END="# <<< radar-edge HAT <<<"
CHANGED=0
REBOOT=0

say() { printf '%-10s %s\n' "$1" "$2"; }

# run a system command: for real on /, listed otherwise
sys() {
  if [ "$DRY_RUN" = 1 ]; then say "would run" "$*"; return 0; fi
  if [ "$SYSTEM" = 0 ]; then say "skipped" "$* (--root)"; return 0; fi
  if ! command -v "$1" >/dev/null 2>&1; then say "skipped" "$* ($1 not installed)"; return 0; fi
  "$@"
}

# like sys, but a failure is a warning (udev/systemd may not be running: chroot, container, image)
sys_soft() {
  sys "$@" || say warning "'$*' failed (exit $?); continuing"
}

# put_file MODE DEST < content   -- writes only when the content differs
put_file() {
  local mode=$1 dest=$ROOT$2 tmp
  tmp=$(mktemp)
  cat >"$tmp"
  if [ -f "$dest" ] && cmp -s "$tmp" "$dest"; then
    rm -f "$tmp"; say unchanged "$2"; return 0
  fi
  local what=installed; [ -e "$dest" ] && what=updated
  if [ "$DRY_RUN" = 1 ]; then rm -f "$tmp"; say "would ${what%ed}" "$2"; return 0; fi
  mkdir -p -- "$(dirname "$dest")"
  install -m "$mode" "$tmp" "$dest"
  rm -f "$tmp"
  CHANGED=1
  say "$what" "$2"
}

remove_file() {
  local dest=$ROOT$1
  [ -e "$dest" ] || [ -L "$dest" ] || return 0
  if [ "$DRY_RUN" = 1 ]; then say "would remove" "$1"; return 0; fi
  rm -f -- "$dest"; say removed "$1"
}

# replace (or add, or with empty content remove) the marked block of a text file
set_block() {
  local file=$ROOT$1 content=$2 tmp
  [ -f "$file" ] || { say skipped "$1 (not found)"; return 0; }
  tmp=$(mktemp)
  awk -v b="$MARK_BEGIN" -v e="$MARK_END" '
    $0 == b { skip = 1; next }
    $0 == e { skip = 0; next }
    !skip { print }' "$file" >"$tmp"
  if [ -n "$content" ]; then printf '%s\n%s\n%s\n' "$MARK_BEGIN" "$content" "$MARK_END" >>"$tmp"; fi
  if cmp -s "$tmp" "$file"; then rm -f "$tmp"; say unchanged "$1"; return 0; fi
  if [ "$DRY_RUN" = 1 ]; then rm -f "$tmp"; say "would edit" "$1"; return 0; fi
  [ -e "$file.radar-edge.orig" ] || cp -p -- "$file" "$file.radar-edge.orig"
  cat "$tmp" >"$file"; rm -f "$tmp"
  CHANGED=1; REBOOT=1
  say edited "$1"
}

boot_dir() {  # bookworm: /boot/firmware; older images: /boot
  if [ -f "$ROOT/boot/firmware/config.txt" ]; then echo /boot/firmware
  elif [ -f "$ROOT/boot/config.txt" ]; then echo /boot
  fi
}

# --- content ------------------------------------------------------------------------------------
udev_rule() {
  cat <<'EOF'
# radar-edge (deploy/install.sh): the Infineon Distance2Go (XMC4200 USB CDC, VID 058B PID 0058).
# Stable name /dev/radar-d2g (use source.url = "d2g:///dev/radar-d2g"), group dialout, mode 0660.
# Other Infineon XMC boards share this USB id: radar-edge identifies the board by its endpoint list.
# ModemManager would probe the port with AT commands and disturb the board: tell it to keep away.
ACTION=="add|change", SUBSYSTEM=="tty", ATTRS{idVendor}=="058b", ATTRS{idProduct}=="0058", SYMLINK+="radar-d2g", GROUP="dialout", MODE="0660", ENV{ID_MM_DEVICE_IGNORE}="1"
EOF
}

can_network() {
  cat <<EOF
# radar-edge (deploy/install.sh): can0 on the MCP2515 HAT, brought up by systemd-networkd.
# Equivalent to: ip link set can0 up type can bitrate $CAN_BITRATE restart-ms $CAN_RESTART_MS
[Match]
Name=can0

[CAN]
BitRate=$CAN_BITRATE
# bus-off recovery (restart-ms): without it a bus-off controller stays silent until a reboot
RestartSec=${CAN_RESTART_MS}ms

[Link]
RequiredForOnline=no
EOF
}

can_link() {
  cat <<EOF
# radar-edge (deploy/install.sh): a longer transmit queue for can0 (default 10 drops object lists
# under load; equivalent to: ip link set can0 txqueuelen $CAN_TXQUEUELEN)
[Match]
OriginalName=can0

[Link]
TransmitQueueLength=$CAN_TXQUEUELEN
EOF
}

hat_block() {
  cat <<EOF
# MCP2515 CAN controller on SPI0 CE0 (crystal $CAN_OSC Hz, interrupt GPIO $CAN_INT) -> can0
dtparam=spi=on
dtoverlay=mcp2515-can0,oscillator=$CAN_OSC,interrupt=$CAN_INT
# RS-485: the PL011 UART (/dev/ttyAMA0) on GPIO 14/15; Bluetooth gives it up (disable-bt)
enable_uart=1
dtoverlay=disable-bt
EOF
}

# --- steps --------------------------------------------------------------------------------------
step_apt() {
  [ "$DO_APT" = 1 ] || { say skipped "system packages (--no-apt)"; return 0; }
  # build-essential + python3-dev: pip compiles the post-FFT kernels (edge/native/*.pyx) on the Pi; without
  # them the package still installs and runs the slower numpy fallback (doctor warns)
  local pkgs="python3 python3-venv python3-pip python3-dev build-essential iproute2 can-utils ca-certificates"
  if [ "$SYSTEM" = 1 ] && [ "$DRY_RUN" = 0 ]; then
    local missing="" p
    for p in $pkgs; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
    [ -n "$missing" ] || { say unchanged "system packages ($pkgs)"; return 0; }
    DEBIAN_FRONTEND=noninteractive sys apt-get install -y -q --no-install-recommends $missing
    CHANGED=1
  else
    sys apt-get install -y --no-install-recommends $pkgs
  fi
}

step_user() {
  if [ "$SYSTEM" = 1 ] && [ "$DRY_RUN" = 0 ]; then
    if id -u "$SVC_USER" >/dev/null 2>&1; then say unchanged "user $SVC_USER"
    else
      useradd --system --user-group --home-dir /var/lib/radar-edge --no-create-home --shell /usr/sbin/nologin \
        --comment "radar-edge service" "$SVC_USER"
      CHANGED=1; say installed "user $SVC_USER"
    fi
    if id -nG "$SVC_USER" | tr ' ' '\n' | grep -qx dialout; then say unchanged "$SVC_USER in dialout"
    else usermod -a -G dialout "$SVC_USER"; CHANGED=1; say installed "$SVC_USER in dialout"; fi
  else
    sys useradd --system --user-group --home-dir /var/lib/radar-edge --shell /usr/sbin/nologin "$SVC_USER"
    sys usermod -a -G dialout "$SVC_USER"
  fi
}

step_dirs() {
  local d
  for d in /var/lib/radar-edge /var/lib/radar-edge/recordings; do
    if [ -d "$ROOT$d" ]; then say unchanged "$d"; continue; fi
    if [ "$DRY_RUN" = 1 ]; then say "would create" "$d"; continue; fi
    mkdir -p -m 0750 -- "$ROOT$d"; CHANGED=1; say installed "$d"
  done
  sys chown -R "$SVC_USER:$SVC_USER" /var/lib/radar-edge
}

step_venv() {
  local venv=$PREFIX/venv spec=${PKG_SPEC:-$SRC_DIR}
  if [ "$SYSTEM" = 0 ] || [ "$DRY_RUN" = 1 ]; then
    sys "$PYTHON" -m venv "$venv"
    if [ -n "$WHEELS" ]; then sys "$venv/bin/pip" install --no-index --find-links "$WHEELS" radar-edge
    else sys "$venv/bin/pip" install "$spec"; fi
    return 0
  fi
  if [ ! -x "$venv/bin/python" ]; then "$PYTHON" -m venv "$venv"; CHANGED=1; say installed "$venv"
  else say unchanged "$venv"; fi
  if [ -n "$WHEELS" ]; then
    "$venv/bin/pip" install -q --no-index --find-links "$WHEELS" --upgrade radar-edge
  else
    "$venv/bin/pip" install -q --upgrade "$spec"
  fi
  say installed "radar-edge $("$venv/bin/python" -c 'import importlib.metadata as m; print(m.version("radar-edge"))') in $venv"
  step_kernels "$venv"
}

# the compiled kernels built by pip above: loaded, or missing (no compiler: the numpy fallback runs, slower)
step_kernels() {
  local venv=$1 line
  line=$(cd / && RADAR_EDGE_KERNELS=1 "$venv/bin/python" -c 'from edge import native; print(native.status()); raise SystemExit(1 if native.missing() else 0)') \
    && say ok "$line" \
    || say warning "${line:-the kernel check did not run}; install build-essential and python3-dev (drop --no-apt) and run $PROG again"
}

step_config() {
  put_file 0644 /etc/radar-edge/radar-edge.example.toml <"$HERE/radar-edge.example.toml"
  if [ -e "$ROOT/etc/radar-edge/radar-edge.toml" ]; then
    say unchanged "/etc/radar-edge/radar-edge.toml (yours; compare with radar-edge.example.toml)"
  else
    put_file 0644 /etc/radar-edge/radar-edge.toml <"$HERE/radar-edge.example.toml"
  fi
}

step_udev() {
  udev_rule | put_file 0644 /etc/udev/rules.d/99-radar-edge-d2g.rules
  sys_soft udevadm control --reload
  sys_soft udevadm trigger --subsystem-match=tty --action=change
}

step_hat() {
  local boot; boot=$(boot_dir)
  if [ "$DO_HAT" = auto ]; then
    [ -n "$boot" ] && DO_HAT=1 || { say skipped "HAT set-up (no config.txt: not a Raspberry Pi; force with --hat)"; return 0; }
  fi
  [ "$DO_HAT" = 1 ] || { say skipped "HAT set-up (--no-hat)"; return 0; }
  if [ -n "$boot" ]; then
    set_block "$boot/config.txt" "$(hat_block)"
    # serial console off: the UART belongs to RS-485 (console=serial0,... / ttyAMA0 removed from cmdline.txt)
    local cmd=$ROOT$boot/cmdline.txt
    if [ -f "$cmd" ] && grep -Eq 'console=(serial0|ttyAMA0|ttyS0),[0-9]+' "$cmd"; then
      if [ "$DRY_RUN" = 1 ]; then say "would edit" "$boot/cmdline.txt (serial console off)"
      else
        [ -e "$cmd.radar-edge.orig" ] || cp -p -- "$cmd" "$cmd.radar-edge.orig"
        sed -i -E 's/[[:space:]]*console=(serial0|ttyAMA0|ttyS0),[0-9]+//g' "$cmd"
        CHANGED=1; REBOOT=1; say edited "$boot/cmdline.txt (serial console off)"
      fi
    else
      say unchanged "$boot/cmdline.txt (no serial console)"
    fi
  else
    say skipped "config.txt overlays (no /boot/firmware/config.txt under ${ROOT:-/})"
  fi
  sys_soft systemctl mask serial-getty@ttyAMA0.service serial-getty@serial0.service
  can_network | put_file 0644 /etc/systemd/network/80-radar-edge-can0.network
  can_link | put_file 0644 /etc/systemd/network/80-radar-edge-can0.link
  sys systemctl enable systemd-networkd.service
}

step_service() {
  put_file 0644 /usr/share/doc/radar-edge/README.md <"$HERE/README.md"
  sed "s#/opt/radar-edge/venv#$PREFIX/venv#g" "$HERE/radar-edge.service" | put_file 0644 /etc/systemd/system/radar-edge.service
  sys_soft systemctl daemon-reload
  sys systemctl enable radar-edge.service
  if [ "$DO_START" = 1 ]; then sys_soft systemctl restart radar-edge.service; fi
}

do_install() {
  step_apt
  step_user
  step_dirs
  step_venv
  step_config
  step_udev
  step_hat
  step_service
  echo
  if [ "$DRY_RUN" = 1 ]; then echo "dry run: nothing changed"
  elif [ "$CHANGED" = 0 ]; then echo "radar-edge: already installed, nothing changed"
  else echo "radar-edge: installed"; fi
  [ "$REBOOT" = 1 ] && echo "reboot to apply the HAT overlays and the console change (sudo reboot)"
  echo "check the installation: $PREFIX/venv/bin/radar-edge doctor --config /etc/radar-edge/radar-edge.toml"
}

do_uninstall() {
  sys_soft systemctl disable --now radar-edge.service
  remove_file /etc/systemd/system/radar-edge.service
  remove_file /etc/udev/rules.d/99-radar-edge-d2g.rules
  remove_file /etc/systemd/network/80-radar-edge-can0.network
  remove_file /etc/systemd/network/80-radar-edge-can0.link
  remove_file /etc/radar-edge/radar-edge.example.toml
  remove_file /usr/share/doc/radar-edge/README.md
  local boot; boot=$(boot_dir)
  [ -n "$boot" ] && set_block "$boot/config.txt" ""
  sys_soft systemctl daemon-reload
  sys_soft udevadm control --reload
  if [ -d "$ROOT$PREFIX" ]; then
    case "$PREFIX" in /|"") die "refusing to remove prefix '$PREFIX'" ;; esac
    if [ "$DRY_RUN" = 1 ]; then say "would remove" "$PREFIX"; else rm -rf -- "$ROOT$PREFIX"; say removed "$PREFIX"; fi
  fi
  if [ "$PURGE" = 1 ]; then
    local d
    for d in /etc/radar-edge /var/lib/radar-edge; do
      [ -e "$ROOT$d" ] || continue
      if [ "$DRY_RUN" = 1 ]; then say "would remove" "$d"; else rm -rf -- "$ROOT$d"; say removed "$d"; fi
    done
    sys userdel "$SVC_USER"
  else
    echo "kept /etc/radar-edge and /var/lib/radar-edge (recordings); --uninstall --purge removes them"
  fi
  echo "serial console and getty masks are left as they are (see deploy/README.md to restore)"
}

if [ "$UNINSTALL" = 1 ]; then do_uninstall; else do_install; fi
