#!/usr/bin/env bash
# make pi-check: the README's set-up and the perception/replay results on aarch64, shown.
#
# Builds once (cached in $PI_CACHE/pi-root) a Debian bookworm arm64 root with debootstrap
# and runs it under qemu-user (Debian's qemu-user-static and binfmt-support). Each run
# starts from a fresh copy of that root ($PI_CACHE/pi-run; only the downloaded .deb
# files and pip's cache are kept between runs), copies the repository's HEAD into it
# (git archive: a clean copy, no venv, no build files), runs the README's set-up there
# (`make .venv/.installed`: system packages, venv, pip, the person models from npm),
# and runs, in the arm64 root and on this host alike,
# `rescue-companion detect --json` on the real_falls frames and a replay of a short
# recorded simulated mission. tools/pi_check.py compares the two and fails (exit 1)
# when people, boxes, victims, urgencies or positions differ beyond its tolerances.
#
# Emulated time says nothing about a Pi's speed: this proves the set-up and the
# results, not the frame rate. Needs root (debootstrap, chroot, binfmt_misc).
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
PI_CACHE=${PI_CACHE:-/var/cache/rescue-companion}
BASE=$PI_CACHE/pi-root  # the debootstrapped root, never run in
PI_ROOT=$PI_CACHE/pi-run  # this run's copy of it
PI_MIRROR=${PI_MIRROR:-http://deb.debian.org/debian}
DATA=${PI_CHECK_DATA:-$REPO/../shared/data/images/real_falls}
OUT=${PI_CHECK_OUT:-$REPO/build/pi-check}
MISSION_PRESET=${PI_CHECK_PRESET:-mixed}
MISSION_S=${PI_CHECK_MISSION_S:-10}
# The heavy emulated work runs at the lowest priority: the machine is shared.
NICE=(nice -n 19)
SRC_IN_ROOT=/opt/rescue-companion
DATA_IN_ROOT=/mnt/real_falls
MISSION_IN_ROOT=/mnt/mission
OUT_IN_ROOT=/mnt/out

say() { printf 'pi-check: %s\n' "$*"; }
die() { printf 'pi-check: error: %s\n' "$*" >&2; exit 2; }

host_packages() {
    local missing=()
    command -v debootstrap >/dev/null 2>&1 || missing+=(debootstrap)
    [ -x /usr/bin/qemu-aarch64-static ] || missing+=(qemu-user-static)
    command -v update-binfmts >/dev/null 2>&1 || missing+=(binfmt-support)
    if [ ${#missing[@]} -gt 0 ]; then
        say "installing ${missing[*]}"
        DEBIAN_FRONTEND=noninteractive apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
    fi
}

binfmt() {
    local dir=/proc/sys/fs/binfmt_misc
    if [ ! -e "$dir/status" ]; then
        say "mounting binfmt_misc on $dir"
        mount -t binfmt_misc binfmt_misc "$dir" || die "cannot mount binfmt_misc (a container without the privilege?)"
    fi
    if [ ! -e "$dir/qemu-aarch64" ]; then
        update-binfmts --enable qemu-aarch64 >/dev/null 2>&1 || true
    fi
    grep -qx enabled "$dir/qemu-aarch64" 2>/dev/null \
        || die "the qemu-aarch64 binfmt handler is not registered ($dir/qemu-aarch64); try: update-binfmts --enable qemu-aarch64"
}

build_root() {
    local stamp=$BASE/.pi-check-root
    if [ -e "$stamp" ]; then
        say "arm64 root cached in $BASE"
        return
    fi
    say "building a Debian bookworm arm64 root in $BASE (once; about 15 minutes)"
    rm -rf "$BASE"
    mkdir -p "$BASE"
    # What the README asks of a fresh machine (python3, make); the set-up installs the rest.
    debootstrap --foreign --arch=arm64 --variant=minbase \
        --include=python3,make,ca-certificates bookworm "$BASE" "$PI_MIRROR"
    install -m 0755 /usr/bin/qemu-aarch64-static "$BASE/usr/bin/"
    "${NICE[@]}" chroot "$BASE" /debootstrap/debootstrap --second-stage
    cat >"$BASE/etc/apt/sources.list" <<SOURCES
deb $PI_MIRROR bookworm main
deb $PI_MIRROR bookworm-updates main
SOURCES
    touch "$stamp"
}

# A site's own certificate authorities (a TLS proxy in front of the registries, as on
# this project's machines) are trusted in the root as on the host: Debian's way
# (/usr/local/share/ca-certificates), and pip is told to use that bundle (it carries
# its own otherwise; the host's pip.conf says the same).
trust_local_cas() {
    local crt found=
    for crt in /usr/local/share/ca-certificates/*.crt; do
        [ -e "$crt" ] || continue
        install -D -m 0644 "$crt" "$PI_ROOT/usr/local/share/ca-certificates/$(basename "$crt")"
        found=1
    done
    if [ -n "$found" ]; then
        in_root update-ca-certificates >/dev/null 2>&1 \
            || die "update-ca-certificates failed in the arm64 root"
    fi
}

# qemu-user shows the emulated programs this host's /proc/cpuinfo (an x86 one), and
# LiteRT's CPU detection (the cpuinfo library, for XNNPACK and its own kernels)
# crashes on it: the first model's allocate_tensors() or invoke() dies of SIGSEGV. A
# Pi 5 has no such file, so the root sees a Pi 5's: four Cortex-A76 cores.
pi5_cpuinfo() {
    local i file=$PI_CACHE/cpuinfo-pi5
    for i in 0 1 2 3; do
        printf 'processor\t: %s\nBogoMIPS\t: 108.00\n' "$i"
        printf 'Features\t: fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid asimdrdm lrcpc dcpop asimddp\n'
        printf 'CPU implementer\t: 0x41\nCPU architecture: 8\nCPU variant\t: 0x4\nCPU part\t: 0xd0b\nCPU revision\t: 1\n\n'
    done >"$file"
    printf 'Revision\t: d04170\nSerial\t\t: 0000000000000000\nModel\t\t: Raspberry Pi 5 Model B Rev 1.0\n' >>"$file"
    mount --bind "$file" "$PI_ROOT/proc/cpuinfo"
    MOUNTED=("$PI_ROOT/proc/cpuinfo" "${MOUNTED[@]}")
}

MOUNTED=()
mount_in_root() {  # SOURCE TARGET [ro]
    mkdir -p "$PI_ROOT$2"
    mount --bind "$1" "$PI_ROOT$2"
    MOUNTED=("$PI_ROOT$2" "${MOUNTED[@]}")
    if [ "${3:-}" = ro ]; then
        mount -o remount,bind,ro "$PI_ROOT$2"
    fi
}
unmount_leftovers() {  # a run killed before its trap: never delete through a bind mount
    local m
    for m in $(awk -v root="$PI_CACHE/" 'index($2, root) == 1 { print $2 }' /proc/mounts | sort -r); do
        umount -l "$m"
    done
    if awk -v root="$PI_CACHE/" 'index($2, root) == 1 { found = 1 } END { exit !found }' /proc/mounts; then
        die "something is still mounted under $PI_CACHE; unmount it by hand"
    fi
}
unmount_all() {
    local m
    for m in "${MOUNTED[@]}"; do
        umount -l "$m" 2>/dev/null || true
    done
    MOUNTED=()
}
# qemu emulates the Pi 5's core (BCM2712: Cortex-A76, Armv8.2 with dot product and
# fp16, no SVE), not its default "max" CPU, so that the libraries pick the kernels a
# Pi 5 runs. QEMU_CPU is read by each emulated program, so it stays in the environment.
PI_CPU=${PI_CPU:-cortex-a76}
in_root() {  # a command in the arm64 root, at the lowest priority, with a clean environment
    QEMU_CPU=$PI_CPU "${NICE[@]}" chroot "$PI_ROOT" /usr/bin/env -i QEMU_CPU="$PI_CPU" \
        HOME=/root LANG=C.UTF-8 PIP_CERT=/etc/ssl/certs/ca-certificates.crt \
        PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
        "$@"
}

# detect and replay with the given data, mission and output folders, on either side
run_side() {  # LABEL DATA MISSION OUT COMMAND... (the command that is rescue-companion)
    local label=$1 data=$2 mission=$3 out=$4
    shift 4
    "$@" detect --json "$data/frames" >"$OUT/$label/detect.jsonl" 2>"$OUT/$label/detect.log" \
        || { tail -n 20 "$OUT/$label/detect.log" >&2; die "$label: rescue-companion detect failed"; }
    "$@" replay --config "$mission/camera.toml" --tlog "$mission/mission.tlog" \
        --frames "$mission/frames" --thermal-frames "$mission/thermal" --out "$out/replay/" \
        >"$OUT/$label/replay.log" 2>&1 \
        || { tail -n 20 "$OUT/$label/replay.log" >&2; die "$label: rescue-companion replay failed"; }
}
# The host runs HEAD too (its copy in $OUT/src, in the host's venv, ahead of the
# working tree's editable install): uncommitted work on the host is not compared.
host_python() {
    env PYTHONPATH="$OUT/src" "${NICE[@]}" "$REPO/.venv/bin/python" "$@"
}

# All in one function: bash reads it whole before running it, so editing this file
# during a run cannot change the run.
main() {
    if [ "$(id -u)" -ne 0 ]; then
        command -v sudo >/dev/null 2>&1 || die "needs root (debootstrap, chroot, binfmt_misc) and there is no sudo"
        exec sudo --preserve-env=PI_MIRROR,PI_CHECK_DATA,PI_CHECK_OUT,PI_CHECK_PRESET,PI_CHECK_MISSION_S,PI_CPU,PI_CACHE \
            bash "${BASH_SOURCE[0]}" "$@"
    fi
    [ -d "$DATA/frames" ] || die "no real_falls frames at $DATA/frames (set PI_CHECK_DATA)"
    [ -x "$REPO/.venv/bin/rescue-companion" ] || die "no host set-up in $REPO/.venv: run make test or make demo first"

    host_packages
    binfmt
    unmount_leftovers
    build_root

    if [ -n "$(git -C "$REPO" status --porcelain --untracked-files=no)" ]; then
        say "note: checking HEAD ($(git -C "$REPO" rev-parse --short HEAD)); uncommitted changes are not part of it"
    fi
    rm -rf "$OUT"
    mkdir -p "$OUT/host" "$OUT/pi" "$OUT/src"
    git -C "$REPO" archive HEAD | tar -x -C "$OUT/src"

    say "a fresh copy of the arm64 root in $PI_ROOT"
    rm -rf "$PI_ROOT"
    cp -a "$BASE" "$PI_ROOT"
    mkdir -p "$PI_CACHE/apt-archives/partial" "$PI_CACHE/pip"
    trap unmount_all EXIT
    mount_in_root "$PI_CACHE/apt-archives" /var/cache/apt/archives
    mount_in_root "$PI_CACHE/pip" /root/.cache/pip
    mount_in_root /proc /proc
    pi5_cpuinfo
    mount_in_root /sys /sys
    mount_in_root /dev /dev
    cp -L /etc/resolv.conf "$PI_ROOT/etc/resolv.conf"
    trust_local_cas

    say "copying HEAD into the arm64 root's $SRC_IN_ROOT"
    rm -rf "${PI_ROOT:?}$SRC_IN_ROOT"
    cp -a "$OUT/src" "$PI_ROOT$SRC_IN_ROOT"

    say "the README's set-up in the arm64 root (make .venv/.installed; log: $OUT/pi/setup.log)"
    start=$(date +%s)
    if ! in_root bash -c "cd $SRC_IN_ROOT && make .venv/.installed" >"$OUT/pi/setup.log" 2>&1; then
        tail -n 30 "$OUT/pi/setup.log" >&2
        die "the set-up failed in the arm64 root (the whole log: $OUT/pi/setup.log)"
    fi
    setup_s=$(( $(date +%s) - start ))
    say "set-up done in ${setup_s} s (emulated)"
    echo "$setup_s" >"$OUT/pi/setup_seconds"
    # The unit file on aarch64's systemd: the project's own tests of it (verify, exposure).
    # Not the console's browser tests: chromium installs but does not run under qemu-user
    # (its child processes fail to start and it aborts; no ptrace there).
    say "the systemd unit's tests in the arm64 root"
    in_root bash -c "cd $SRC_IN_ROOT && .venv/bin/python -m pytest -q -p no:xdist \
        -p no:cacheprovider tests/test_systemd_unit.py" >"$OUT/pi/systemd-tests.log" 2>&1 \
        || { tail -n 30 "$OUT/pi/systemd-tests.log" >&2; die "the systemd unit's tests failed in the arm64 root"; }
    tail -n 1 "$OUT/pi/systemd-tests.log"

    # The same mission and pictures on both sides: the mission is recorded on the host
    # (simulated time: the same seed gives the same frames), then bind-mounted read-only.
    say "recording a ${MISSION_S} s '$MISSION_PRESET' mission on the host (both cameras)"
    host_python -m scenarios.cli record --preset "$MISSION_PRESET" --out "$OUT/mission" \
        --duration-s "$MISSION_S" --fps 5 --start-unix-s 1767000000 >"$OUT/host/record.log" 2>&1 \
        || { tail -n 20 "$OUT/host/record.log" >&2; die "rescue-sim record failed"; }
    mount_in_root "$DATA" "$DATA_IN_ROOT" ro
    mount_in_root "$OUT/mission" "$MISSION_IN_ROOT" ro
    mount_in_root "$OUT/pi" "$OUT_IN_ROOT"

    say "detect and replay on the host"
    start=$(date +%s)
    run_side host "$DATA" "$OUT/mission" "$OUT/host" host_python -m companion.commands.cli
    echo $(( $(date +%s) - start )) >"$OUT/host/run_seconds"

    say "detect and replay on aarch64 (emulated)"
    start=$(date +%s)
    run_side pi "$DATA_IN_ROOT" "$MISSION_IN_ROOT" "$OUT_IN_ROOT" \
        in_root "$SRC_IN_ROOT/.venv/bin/rescue-companion"
    echo $(( $(date +%s) - start )) >"$OUT/pi/run_seconds"
    in_root "$SRC_IN_ROOT/.venv/bin/python" -c \
        'import platform, sys; print(platform.machine(), platform.python_version())' \
        >"$OUT/pi/platform"
    in_root "$SRC_IN_ROOT/.venv/bin/pip" freeze --exclude-editable >"$OUT/pi/pip-freeze.txt"
    say "aarch64 side: $(cat "$OUT/pi/platform"), set-up ${setup_s} s, detect + replay $(cat "$OUT/pi/run_seconds") s (emulated: no Pi figure)"

    # What a Pi 5 must compute, counted on the host (the same models, the same frames).
    say "model runs a frame and multiply-accumulates a run"
    frames=$(find "$DATA/frames" -maxdepth 1 -type f | wc -l)
    mission_frames=$(find "$OUT/mission/frames" -maxdepth 1 -type f | wc -l)
    host_python "$OUT/src/tools/pi_check.py" ops "$OUT/ops.json" \
        --detect-frames "$frames" --replay-frames "$mission_frames" -- \
        detect --json "$DATA/frames" / \
        replay --config "$OUT/mission/camera.toml" --tlog "$OUT/mission/mission.tlog" \
        --frames "$OUT/mission/frames" --thermal-frames "$OUT/mission/thermal" \
        --out "$OUT/ops-replay/" 2>"$OUT/ops.log"

    say "comparing aarch64 with the host"
    host_python "$OUT/src/tools/pi_check.py" compare "$OUT/host" "$OUT/pi"
}

main "$@"
