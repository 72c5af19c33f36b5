#!/bin/sh
# Serve the Cortex-M4F image of KIND (dcmotor, valve, plate) in QEMU's mps2-an386 (Cortex-M4 with
# FPU) with its UART on a new pty; prints `pty /dev/pts/N` as its first line, then runs until
# killed. ARITH: f32 (default) or f64. Build first: make -C firmware m4.
set -eu
KIND=${1:?usage: firmware/qemu.sh dcmotor|valve|plate [f32|f64]}
ARITH=${2:-f32}
case "$KIND" in dcmotor|valve|plate) ;; *) echo "qemu.sh: KIND must be dcmotor, valve or plate, got $KIND" >&2; exit 2;; esac
case "$ARITH" in f32|f64) ;; *) echo "qemu.sh: ARITH must be f32 or f64, got $ARITH" >&2; exit 2;; esac
HERE=$(cd "$(dirname "$0")" && pwd)
IMAGE=${LAB_M4_BUILD:-$HERE/build}/m4/labdevice-$KIND-$ARITH.elf
[ -f "$IMAGE" ] || { echo "qemu.sh: no $IMAGE (run make -C firmware m4)" >&2; exit 2; }
# QEMU names the pty it made: "char device redirected to /dev/pts/N (label serial0)"
LOG=$(mktemp)
qemu-system-arm -M mps2-an386 -nographic -monitor none -serial pty -kernel "$IMAGE" >"$LOG" 2>&1 &
QEMU=$!
trap 'kill $QEMU 2>/dev/null; rm -f "$LOG"' EXIT INT TERM
dev=""
for _ in $(seq 200); do
    dev=$(sed -n 's#.*redirected to \(/dev/pts/[0-9]*\).*#\1#p' "$LOG")
    [ -n "$dev" ] && break
    kill -0 $QEMU 2>/dev/null || { cat "$LOG" >&2; exit 1; }
    sleep 0.05
done
[ -n "$dev" ] || { echo "qemu.sh: QEMU named no pty" >&2; exit 1; }
# hold the pty's slave open: QEMU sends and takes bytes only while it sees the pty connected, and
# it looks for a connection once a second (a host opening the pty later would lose its first frames)
exec 4<>"$dev"
sleep 1.2
echo "pty $dev"
wait $QEMU
