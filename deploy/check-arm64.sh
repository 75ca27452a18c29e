#!/usr/bin/env bash
# Checks the Raspberry Pi install on an x86-64 machine: a Debian bookworm arm64 root file system
# (= Raspberry Pi OS 64-bit userland) under qemu user-mode emulation. Recipe and traps:
# ../shared/reference/arm64.md. Steps:
#   1. binfmt_misc + qemu-aarch64; debootstrap bookworm arm64 (cached in --cache, ~4 min the first time)
#   2. a fresh copy of the cached root; /proc and /dev mounted, NO sysfs (onnxruntime dies under qemu
#      with the host's /sys) -- /sys/devices/system/cpu/{possible,present} are faked instead
#   3. the radar-edge wheel built on the host + its dependencies downloaded for aarch64/cp311
#   4. deploy/install.sh --wheels inside the chroot (offline pip, service user, config, udev, unit)
#   5. radar-edge doctor (reported; no board, no HAT in a chroot), then N-frame replays of a simulated
#      SIMO recording (lane profile) and a simulated Distance2Go recording (surveillance profile), and
#      a run as the service does it (installed configuration, outputs, recorder, service user)
# Timings inside qemu say nothing about the Pi (emulation is 15-30x slower). Not part of the test
# suite: it needs root, the network (debootstrap, pip download) and ~6 minutes.
set -euo pipefail

PROG=$(basename "$0")
SRC=$(cd "$(dirname "$0")/.." && pwd)
CACHE=/var/cache/radar-edge-arm64
WORK=""
FRAMES=100
KEEP=0
CPU=cortex-a72
PY=${PYTHON:-python3}

usage() {
  cat <<EOF
usage: $PROG [--cache DIR] [--work DIR] [--frames N] [--cpu cortex-a72|cortex-a76] [--keep]

Installs radar-edge into a Debian bookworm arm64 root under qemu and runs doctor and a replay
through both profiles. Needs root and: apt-get install qemu-user-static debootstrap binfmt-support

  --cache DIR   where the debootstrapped root is kept between runs (default $CACHE)
  --work DIR    scratch directory (default: a new one under /var/tmp)
  --frames N    frames per replay (default $FRAMES)
  --cpu NAME    QEMU_CPU: cortex-a72 = Raspberry Pi 4, cortex-a76 = Pi 5 (default $CPU)
  --keep        keep the scratch root for inspection

examples:
  sudo deploy/check-arm64.sh
  sudo deploy/check-arm64.sh --frames 20 --cpu cortex-a76 --keep
EOF
}

while [ $# -gt 0 ]; do
  case "$1" in
    --cache) CACHE=$2; shift ;;
    --work) WORK=$2; shift ;;
    --frames) FRAMES=$2; shift ;;
    --cpu) CPU=$2; shift ;;
    --keep) KEEP=1 ;;
    -h|--help) usage; exit 0 ;;
    *) usage >&2; echo "$PROG: unknown option $1" >&2; exit 2 ;;
  esac
  shift
done

[ "$(id -u)" = 0 ] || { echo "$PROG: needs root (chroot, mounts)" >&2; exit 2; }
for t in debootstrap qemu-aarch64-static update-binfmts; do
  command -v "$t" >/dev/null || { echo "$PROG: $t missing: apt-get install qemu-user-static debootstrap binfmt-support" >&2; exit 2; }
done

t0=$(date +%s)
log() { printf '[%4ss] %s\n' "$(( $(date +%s) - t0 ))" "$*"; }

# --- 1. binfmt + cached root -------------------------------------------------------------------
mountpoint -q /proc/sys/fs/binfmt_misc || mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc
update-binfmts --enable qemu-aarch64 2>/dev/null || true
[ -e /proc/sys/fs/binfmt_misc/qemu-aarch64 ] || { echo "$PROG: qemu-aarch64 binfmt not registered" >&2; exit 1; }
mkdir -p "$CACHE"
if [ ! -x "$CACHE/rootfs/usr/bin/python3" ]; then
  log "debootstrap bookworm arm64 into $CACHE/rootfs (about 4 minutes)"
  rm -rf "$CACHE/rootfs.tmp"
  debootstrap --arch=arm64 --variant=minbase --include=python3,python3-venv,python3-pip,ca-certificates \
    bookworm "$CACHE/rootfs.tmp" >"$CACHE/debootstrap.log" 2>&1 || { tail -20 "$CACHE/debootstrap.log"; exit 1; }
  mv "$CACHE/rootfs.tmp" "$CACHE/rootfs"
fi

[ -n "$WORK" ] || WORK=$(mktemp -d /var/tmp/radar-edge-arm64.XXXXXX)
ROOT=$WORK/root
cleanup() {
  for m in "$ROOT/dev/pts" "$ROOT/dev" "$ROOT/proc"; do mountpoint -q "$m" && umount -l "$m"; done
  if [ "$KEEP" = 0 ]; then rm -rf "$WORK"; else echo "kept $ROOT"; fi
}
trap cleanup EXIT
log "fresh root in $ROOT"
rm -rf "$ROOT"; cp -a "$CACHE/rootfs" "$ROOT"

# --- 2. mounts: proc and dev, never sys ------------------------------------------------------------
mount -t proc proc "$ROOT/proc"
mount --bind /dev "$ROOT/dev"
mount --bind /dev/pts "$ROOT/dev/pts"
mkdir -p "$ROOT/sys/devices/system/cpu"
echo 0-1 >"$ROOT/sys/devices/system/cpu/possible"
echo 0-1 >"$ROOT/sys/devices/system/cpu/present"

# --- 3. wheels -------------------------------------------------------------------------------------
WHEELS=$WORK/wheels
mkdir -p "$WHEELS"
log "building the radar-edge wheel"
"$PY" -m pip wheel -q --no-deps -w "$WHEELS" "$SRC" >/dev/null
log "downloading aarch64 wheels of the dependencies"
"$PY" -m pip download -q --only-binary=:all: --python-version 3.11 --implementation cp --abi cp311 --abi abi3 --abi none \
  --platform manylinux_2_28_aarch64 --platform manylinux_2_27_aarch64 --platform manylinux_2_17_aarch64 \
  --platform manylinux2014_aarch64 --platform any -d "$WHEELS" "$(ls "$WHEELS"/radar_edge-*.whl)"
ls "$WHEELS" | sed 's/^/    /'
cp -r "$WHEELS" "$ROOT/wheels"
mkdir -p "$ROOT/opt/src"
cp -r "$SRC/deploy" "$ROOT/opt/src/"

in_root() {
  env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 QEMU_CPU="$CPU" chroot "$ROOT" "$@"
}
log "guest: $(in_root uname -m), $(in_root python3 --version)"

# --- 4. install ------------------------------------------------------------------------------------
log "deploy/install.sh --wheels /wheels (inside the arm64 root)"
in_root bash /opt/src/deploy/install.sh --wheels /wheels --no-apt --no-hat
log "second run must change nothing"
in_root bash /opt/src/deploy/install.sh --wheels /wheels --no-apt --no-hat | tail -3
RE=/opt/radar-edge/venv/bin/radar-edge
in_root id radar-edge

# --- 5. doctor and replays -------------------------------------------------------------------------
log "radar-edge doctor (a chroot has no board and no HAT: failures expected, each with its fix)"
in_root $RE doctor --config /etc/radar-edge/radar-edge.toml || log "doctor exit status $? (see above)"

status=0
replay() {  # scenario profile
  local scen=$1 profile=$2 rec=/var/tmp/$1.npz
  log "simulate $scen ($FRAMES frames) -> $rec"
  in_root $RE simulate --scenario "$scen" --frames "$FRAMES" --out "$rec"
  log "replay $rec through the minimal pipeline (runtime baseline)"
  in_root $RE replay "$rec" --speed 0 --frames "$FRAMES" --profile minimal --no-outputs --status-every 0 \
    || { log "FAILED: minimal pipeline on $scen"; status=1; }
  log "replay $rec through the $profile profile"
  if in_root $RE replay "$rec" --speed 0 --frames "$FRAMES" --profile "$profile" --no-outputs --status-every 0; then
    log "OK: $profile profile, $FRAMES frames"
  else
    log "FAILED: $profile profile"; status=1
  fi
}
replay highway4 lane
replay tavanti-test1 surveillance

# as the service runs it: the installed configuration (Modbus TCP, RTU and CAN configured but absent
# in a chroot -- logged, never fatal -- and the event recorder on), as the service user
log "service-like run: installed config, outputs and recorder on, as user radar-edge"
if in_root setpriv --reuid=radar-edge --regid=radar-edge --init-groups env HOME=/var/lib/radar-edge \
     $RE run --config /etc/radar-edge/radar-edge.toml --source "replay:///var/tmp/tavanti-test1.npz?speed=0" \
     --frames "$FRAMES" --status-every 0 --set ops.recorder.trigger=tracks --set ops.recorder.min_free_mb=0; then
  log "OK: service-like run; recordings: $(in_root sh -c 'ls /var/lib/radar-edge/recordings | wc -l')"
else
  log "FAILED: service-like run"; status=1
fi
log "done (status $status)"
exit $status
