#!/bin/sh
# Make sure the Debian packages for the firmware (and, with "hil", for the emulated board
# of the hardware-in-the-loop tests) are installed; install them with apt-get when missing
# and running as root. Exit 0 when everything is there, else print ONE line and exit 1.
#   firmware/tools/ensure-toolchain.sh [fw|hil|host]   (host: only the host C compiler)
set -u
what=${1:-fw}
need=""
if [ "$what" != host ]; then
    command -v avr-gcc >/dev/null 2>&1 || need="$need gcc-avr binutils-avr"
    [ -f /usr/lib/avr/include/avr/io.h ] || need="$need avr-libc"
fi
if [ "$what" = host ]; then
    command -v cc >/dev/null 2>&1 || need="$need gcc libc6-dev"
fi
if [ "$what" = hil ]; then
    command -v cc >/dev/null 2>&1 || need="$need gcc libc6-dev"
    [ -f /usr/include/simavr/sim_avr.h ] || need="$need libsimavr-dev simavr"
    [ -f /usr/include/libelf.h ] || [ -f /usr/include/libelf/libelf.h ] || need="$need libelf-dev"
    command -v pkg-config >/dev/null 2>&1 || need="$need pkg-config"
fi
[ -z "$need" ] && exit 0
if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "firmware toolchain missing (apt packages:$need); install them as root" >&2
    exit 1
fi
echo "installing apt packages:$need" >&2
export DEBIAN_FRONTEND=noninteractive
if ! { apt-get install -y -q --no-install-recommends $need >/dev/null 2>&1 ||
       { apt-get update -q >/dev/null 2>&1 &&
         apt-get install -y -q --no-install-recommends $need >/dev/null 2>&1; }; }; then
    echo "firmware toolchain missing and apt-get could not install$need (offline?)" >&2
    exit 1
fi
exit 0
