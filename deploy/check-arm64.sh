#!/usr/bin/env bash
# Checks the Raspberry Pi install on an x86-64 machine: a Debian bookworm arm64 root file system
# (= Raspberry Pi OS 64-bit userland) under qemu user-mode emulation. Recipe and traps:
# ../shared/reference/arm64.md. Steps:
#   1. binfmt_misc + qemu-aarch64; debootstrap bookworm arm64 (cached in --cache, ~4 min the first time)
#   2. a fresh copy of the cached root; /proc and /dev mounted, NO sysfs (onnxruntime dies under qemu
#      with the host's /sys) -- /sys/devices/system/cpu/{possible,present} are faked instead
#   3. the radar-edge sdist built on the host (the kernels' .pyx, no host binaries) + its dependencies and
#      build requirements (setuptools, Cython, numpy) downloaded for aarch64/cp311
#   4. deploy/install.sh --wheels inside the chroot (offline pip compiles the kernels with the root's gcc;
#      service user, config, udev, unit)
#   5. the arm64 kernels: built and loaded (edge.native), and equal to the numpy reference end to end
#      (python -m edge.native.check, lane and surveillance profiles: outputs with and without the kernels)
#   6. radar-edge doctor (reported; no board, no HAT in a chroot), then N-frame replays of a simulated
#      SIMO recording (lane profile) and a simulated Distance2Go recording (surveillance profile), and
#      a run as the service does it (installed configuration, outputs, recorder, service user)
# Timings inside qemu say nothing about the Pi (emulation is 15-30x slower). Not part of the test
# suite: it needs root, the network (debootstrap, apt, pip download) and ~10 minutes.
set -euo pipefail

PROG=$(basename "$0")
SRC=$(cd "$(dirname "$0")/.." && pwd)
CACHE=/var/cache/radar-edge-arm64
WORK=""
FRAMES=100
CHECK_FRAMES=40
KEEP=0
CPU=cortex-a72
PY=${PYTHON:-python3}

usage() {
  cat <<EOF
usage: $PROG [--cache DIR] [--work DIR] [--frames N] [--check-frames N] [--cpu cortex-a72|cortex-a76] [--keep]

Installs radar-edge into a Debian bookworm arm64 root under qemu and runs doctor and a replay
through both profiles. Needs root and: apt-get install qemu-user-static debootstrap binfmt-support

  --cache DIR   where the debootstrapped root is kept between runs (default $CACHE)
  --work DIR    scratch directory (default: a new one under /var/tmp)
  --frames N    frames per replay (default $FRAMES)
  --check-frames N  frames of the kernels-against-numpy comparison (default $CHECK_FRAMES; two pipeline
                runs under emulation)
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
    --check-frames) CHECK_FRAMES=$2; shift ;;
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
  debootstrap --arch=arm64 --variant=minbase \
    --include=python3,python3-venv,python3-pip,python3-dev,build-essential,ca-certificates \
    bookworm "$CACHE/rootfs.tmp" >"$CACHE/debootstrap.log" 2>&1 || { tail -20 "$CACHE/debootstrap.log"; exit 1; }
  mv "$CACHE/rootfs.tmp" "$CACHE/rootfs"
fi
if [ ! -x "$CACHE/rootfs/usr/bin/gcc" ] || [ ! -e "$CACHE/rootfs/usr/include/python3.11/Python.h" ]; then
  # a root cached before the kernels: add the toolchain deploy/install.sh installs on the Pi
  log "adding build-essential python3-dev to the cached root"
  cp /etc/resolv.conf "$CACHE/rootfs/etc/resolv.conf"
  mount -t proc proc "$CACHE/rootfs/proc"
  env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin DEBIAN_FRONTEND=noninteractive chroot "$CACHE/rootfs" \
    sh -c 'apt-get update -qq && apt-get install -y -qq --no-install-recommends build-essential python3-dev' \
    >"$CACHE/toolchain.log" 2>&1 || { umount -l "$CACHE/rootfs/proc"; tail -20 "$CACHE/toolchain.log"; exit 1; }
  umount -l "$CACHE/rootfs/proc"
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
log "building the radar-edge sdist (compiled inside the arm64 root, as on the Pi)"
(cd "$SRC" && RADAR_EDGE_BUILD_KERNELS=0 "$PY" setup.py -q sdist -d "$WHEELS" >/dev/null 2>&1)
tar tzf "$WHEELS"/radar_edge-*.tar.gz | grep -q 'edge/native/_probe.pyx' || { echo "$PROG: the sdist lacks the kernels' .pyx" >&2; exit 1; }
log "downloading aarch64 wheels of the dependencies and of the build requirements"
mapfile -t REQS < <(cd "$SRC" && "$PY" -c 'import tomllib; p = tomllib.load(open("pyproject.toml", "rb"))
print("\n".join(dict.fromkeys(p["project"]["dependencies"] + p["build-system"]["requires"]))))')
"$PY" -m pip download -q --only-binary=:all: --python-version 3.11 --implementation cp --abi cp311 --abi abi3 --abi none \
  --platform manylinux_2_28_aarch64 --platform manylinux_2_27_aarch64 --platform manylinux_2_17_aarch64 \
  --platform manylinux2014_aarch64 --platform any -d "$WHEELS" "${REQS[@]}"
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

# --- 5. the arm64 kernels: built, loaded, equal to the numpy reference -----------------------------
PYV=/opt/radar-edge/venv/bin/python
status=0
log "kernels: $(in_root $PYV -c 'from edge import native; print(native.status())')"
log "kernels against the numpy reference, lane profile, $CHECK_FRAMES frames of highway4-traffic"
if in_root $PYV -m edge.native.check --scenario highway4-traffic --frames "$CHECK_FRAMES"; then
  log "OK: arm64 kernels equal the numpy reference"
else
  log "FAILED: arm64 kernels (exit $?: 1 = different outputs, 2 = not built)"; status=1
fi
log "kernels against the numpy reference, surveillance profile, $CHECK_FRAMES frames of tavanti-test1"
if in_root $PYV -m edge.native.check --profile surveillance --frames "$CHECK_FRAMES"; then
  log "OK: arm64 surveillance kernels equal the numpy reference"
else
  log "FAILED: arm64 surveillance kernels (exit $?: 1 = different outputs, 2 = not built)"; status=1
fi

# --- 6. doctor and replays -------------------------------------------------------------------------
log "radar-edge doctor (a chroot has no board and no HAT: failures expected, each with its fix)"
in_root $RE doctor --config /etc/radar-edge/radar-edge.toml || log "doctor exit status $? (see above)"

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
