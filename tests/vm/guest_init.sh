#!/bin/busybox sh
# /init of the VM tier's initramfs: loads vivid and v4l2loopback, streams
# vivid -> gazesplat live -> loopback, reads the loopback back with v4l2-ctl,
# unbinds and rebinds vivid mid-stream, then waits for the host to hot-plug
# a USB device. Lines starting "GS-VM:" are read by vm_live.py.
/bin/busybox --install -s /bin
export PATH=/bin:/usr/bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
mount -t tmpfs tmp /tmp
mkdir -p /run && mount -t tmpfs run /run

ok=1
say() { echo "GS-VM: $*"; }
fail() { say "FAIL $*"; ok=0; }
now() { cut -d' ' -f1 /proc/uptime; }
# Milliseconds between two uptime values.
ms() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%d", (b - a) * 1000 }'; }
# Lines of the live log matching $1; 0 before the log exists (the background
# job's redirect may not have created it yet: an empty count would make
# every numeric test below fail as "bad number" and end the waits at once).
count() { n=$(grep -c "$1" /tmp/live.log 2>/dev/null); echo "${n:-0}"; }

say "boot $(now) s"
while read -r m args; do
    insmod "/modules/$m" $args || fail "insmod $m"
done < /modules/order
[ -e /dev/video0 ] && [ -e /dev/video9 ] || fail "video nodes missing: $(ls /dev/video*)"
say "modules loaded $(now) s"

if [ -x /usr/lib/systemd/systemd-udevd ]; then # libusb's hotplug listens to udev's events
    mkdir -p /run/udev
    /usr/lib/systemd/systemd-udevd --daemon --resolve-names=never 2>/tmp/udevd.log &&
        say "udevd started" && udev=1
fi

gazesplat live --in /dev/video0 --out /dev/video9 --size 640x480 --fps 30 --stats 2 \
    --hotplug-any 2>/tmp/live.log &
live=$!

# 1. Stream: the loopback turns into a capture device and delivers frames.
i=0
while [ "$(count 'capture: streaming')" -lt 1 ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
[ "$(count 'capture: streaming')" -ge 1 ] || fail "gazesplat never streamed"
v4l2-ctl -d /dev/video9 --get-fmt-video | sed 's/^/GS-VM: loopback /'
t0=$(now)
timeout 20 v4l2-ctl -d /dev/video9 --stream-mmap --stream-count=60 --stream-to=/tmp/out.yuv 2>/dev/null
t1=$(now)
size=$(wc -c < /tmp/out.yuv 2>/dev/null || echo 0)
[ "$size" -eq $((60 * 640 * 480 * 2)) ] || fail "read $size bytes from the loopback"
say "loopback read 60 frames in $(ms "$t0" "$t1") ms"

# 2. Unbind vivid mid-stream (DQBUF answers EINVAL), rebind, time recovery.
before=$(count 'capture: streaming')
echo vivid.0 > /sys/bus/platform/drivers/vivid/unbind || fail "unbind"
sleep 1
grep -q 'capture lost' /tmp/live.log || fail "loss not noticed"
# While the camera is gone the loopback carries "no video" frames (10/s).
timeout 5 v4l2-ctl -d /dev/video9 --stream-mmap --stream-count=3 --stream-to=/tmp/ph.yuv 2>/dev/null
fs=$((640 * 480 * 2))
size=$(wc -c < /tmp/ph.yuv 2>/dev/null || echo 0)
say "while unbound: read $size bytes of placeholder frames (want $((3 * fs)))"
[ "$size" -eq $((3 * fs)) ] || fail "no placeholder frames while the camera is gone"
# The placeholder is one still frame, dark grey (luma 43) with light text;
# vivid's colour bars start with a white column.
dd if=/tmp/ph.yuv of=/tmp/ph0 bs=$fs count=1 2>/dev/null
dd if=/tmp/ph.yuv of=/tmp/ph2 bs=$fs skip=2 count=1 2>/dev/null
cmp -s /tmp/ph0 /tmp/ph2 || fail "placeholder frames differ from each other"
luma=$(od -An -tu1 -N1 /tmp/ph0 | tr -d ' ')
[ "${luma:-255}" -lt 64 ] || fail "not the placeholder: first luma ${luma:-none}"
rm -f /tmp/ph.yuv /tmp/ph0 /tmp/ph2
echo vivid.0 > /sys/bus/platform/drivers/vivid/bind || fail "bind"
tb=$(now)
while [ "$(count 'capture: streaming')" -le "$before" ]; do
    [ "$(ms "$tb" "$(now)")" -gt 20000 ] && break
    sleep 0.05
done
# Recovery = the wait for the next open attempt (the back-off, at most 1 s:
# gazesplat's part) + the open, STREAMON and first frame (the driver's part,
# which the capture reports). The 2 s bound is on the first, read from the
# live log's own time stamps (CLOCK_MONOTONIC, the clock /proc/uptime counts
# here), so a guest that the host starves does not fail it by emulating the
# driver slowly; the polling above only has to notice eventually.
if [ "$(count 'capture: streaming')" -gt "$before" ]; then
    line=$(grep 'capture: streaming' /tmp/live.log | tail -1)
    ts=$(echo "$line" | sed 's/^\[\([0-9.]*\)\].*/\1/')
    ff=$(echo "$line" | sed -n 's/.*first frame \([0-9.]*\) ms after open.*/\1/p')
    rec=$(ms "$tb" "$ts")
    wait=$(awk -v r="$rec" -v f="${ff:-0}" 'BEGIN { printf "%d", r - f }')
    say "recovered ${rec} ms after rebind: open began after ${wait} ms, first frame ${ff:-?} ms after it"
    [ -n "$ff" ] || fail "no first-frame time in: $line"
    [ "$wait" -le 2000 ] || fail "the reopen began ${wait} ms after the rebind (bound 2000)"
else
    fail "no recovery within 20 s of the rebind"
fi
# vivid restarts at 5 fps after a rebind: the rate first agreed must be back.
rate() { grep 'capture: streaming' /tmp/live.log | sed -n "$1" | sed 's/.* at \([0-9/]*\) fps.*/\1/'; }
[ "$(rate '$p')" = "$(rate '1p')" ] || fail "fps not re-applied: $(rate '1p') then $(rate '$p')"
say "rate $(rate '1p') fps before, $(rate '$p') after the rebind"
rm -f /tmp/out.yuv
timeout 20 v4l2-ctl -d /dev/video9 --stream-mmap --stream-count=15 --stream-to=/tmp/out.yuv 2>/dev/null
size=$(wc -c < /tmp/out.yuv 2>/dev/null || echo 0)
[ "$size" -eq $((15 * 640 * 480 * 2)) ] || fail "after rebind read $size bytes from the loopback"

# 3. USB hot-plug: the host adds a device through the qemu monitor.
say "HOTPLUG-READY"
i=0
while ! grep -q 'hotplug: .* arrived' /tmp/live.log && [ $i -lt 30 ]; do sleep 0.5; i=$((i + 1)); done
if grep -q 'hotplug: .* arrived' /tmp/live.log; then
    say "hotplug seen: $(grep 'hotplug: .* arrived' /tmp/live.log | head -1)"
else
    say "HOTPLUG-MISSED $(ls /sys/bus/usb/devices | tr '\n' ' ')"
    [ "${udev:-0}" = 1 ] && fail "libusb hotplug did not fire"
fi

# SIGTERM must end it promptly; a hang here would otherwise hang the guest.
kill -TERM $live
i=0
while kill -0 $live 2>/dev/null && [ $i -lt 150 ]; do sleep 0.1; i=$((i + 1)); done
if kill -0 $live 2>/dev/null; then
    fail "gazesplat live still running 15 s after SIGTERM"
    for t in /proc/$live/task/*; do
        say "live thread ${t##*/} $(cat $t/comm) in $(cat $t/wchan 2>/dev/null)"
        sed 's/^/GS-VM:   /' $t/stack 2>/dev/null
    done
    kill -KILL $live
fi
wait $live
rc=$?
[ $rc = 0 ] || fail "gazesplat live exited with status $rc after SIGTERM"
say "live stopped $(now) s"
sed 's/^/GS-VM: live| /' /tmp/live.log
[ -s /tmp/udevd.log ] && sed 's/^/GS-VM: udevd| /' /tmp/udevd.log
[ $ok = 1 ] && say "RESULT PASS" || say "RESULT FAIL"
poweroff -f
