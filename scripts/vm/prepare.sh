#!/usr/bin/env bash
# Prepares what the VM test tier boots, into a cache directory (default
# build/vm-cache), without touching the host's kernel or /boot:
#   - Debian 12's kernel image and modules (vivid.ko ships with it),
#   - v4l2loopback.ko built from Debian's v4l2loopback-dkms source against
#     the matching linux-headers,
#   - modules.dep for the guest (depmod -b),
#   - udev's daemon (udev, libsystemd-shared): libusb's hotplug listens to
#     the events udevd re-broadcasts, so the guest runs it.
# Packages come with `apt-get download` and are unpacked with dpkg-deb -x.
# Each step is skipped when its result is already in the cache, so only the
# first run costs a download and a module build. Needs no root.
#
# Usage: scripts/vm/prepare.sh [CACHE_DIR]    prints the kernel release last.
set -euo pipefail
cache=$(realpath -m "${1:-build/vm-cache}")
mkdir -p "$cache/debs" "$cache/root"
cd "$cache"

# The kernel ABI the archive offers now, e.g. 6.1.0-56.
img_pkg=$(apt-cache depends linux-image-amd64 | sed -n 's/^ *Depends: \(linux-image-[0-9].*-amd64\)$/\1/p' | head -1)
[ -n "$img_pkg" ] || { echo "prepare: cannot resolve linux-image-amd64" >&2; exit 1; }
abi=${img_pkg#linux-image-}; abi=${abi%-amd64}
krel="$abi-amd64"
hdr_pkg="linux-headers-$krel"
hdr_deps=$(apt-cache depends "$hdr_pkg" | sed -n 's/^ *Depends: \(linux-headers-.*-common\|linux-kbuild-.*\)$/\1/p')

fetch() { # package...
    for p in "$@"; do
        if ! ls "debs/${p}_"*.deb >/dev/null 2>&1; then
            (cd debs && apt-get download -q "$p" >/dev/null)
        fi
    done
}
stamp=root/.unpacked-$krel
if [ ! -e "$stamp" ]; then
    pkgs="$img_pkg $hdr_pkg $hdr_deps v4l2loopback-dkms udev libsystemd-shared"
    fetch $pkgs
    for p in $pkgs; do
        dpkg-deb -x debs/"${p}_"*.deb root
    done
    # The headers refer to their -common half and to kbuild through absolute
    # links (/usr/src/..., /usr/lib/linux-kbuild-*): point them into root.
    find root/usr/src root/usr/lib -maxdepth 3 -type l -lname '/usr/*' | while read -r l; do
        ln -sfn "$cache/root$(readlink "$l")" "$l"
    done
    sed -i "s|^include /usr/src/|include $cache/root/usr/src/|" \
        root/usr/src/linux-headers-"$krel"/Makefile
    touch "$stamp"
fi

kdir=root/usr/src/linux-headers-$krel
mdir=root/lib/modules/$krel
ko=$mdir/extra/v4l2loopback.ko
if [ ! -e "$ko" ]; then
    src=$(ls -d root/usr/src/v4l2loopback-* | head -1)
    rm -rf build-v4l2loopback && cp -r "$src" build-v4l2loopback
    make -s -C "$kdir" M="$cache/build-v4l2loopback" KERNELRELEASE="$krel" \
        -j"${GS_JOBS:-2}" modules >build-v4l2loopback.log 2>&1 ||
        { tail -30 build-v4l2loopback.log >&2; exit 1; }
    mkdir -p "$mdir/extra"
    cp build-v4l2loopback/v4l2loopback.ko "$ko"
fi
if [ ! -e "$mdir/modules.dep" ] || [ "$ko" -nt "$mdir/modules.dep" ]; then
    /sbin/depmod -b "$cache/root" "$krel"
fi
echo "$krel"
