#!/usr/bin/busybox sh
# The checks of the systemd VM tier, run by the guest's systemd (PID 1) as
# gs-vm-test.service once sockets.target is up. The guest holds the .deb that
# cpack made; the checks install it and enable the socket with the commands
# docs/usage.md gives ("Install and package"), then check the installed
# system: the service itself must not run before the first client connects. Lines
# starting "GS-VM:" are read by vm_systemd.py (through vm_live.boot, which
# hot-plugs a USB keyboard on "HOTPLUG-READY").
mkdir -p /usr/local/bin && /usr/bin/busybox --install -s /usr/local/bin
export PATH=/usr/sbin:/usr/bin:/usr/local/bin

ok=1
U=gazesplatd.service
S=gazesplatd.socket
SOCK=/run/gazesplat/gazesplatd.sock
say() { echo "GS-VM: $*"; }
pass() { say "PASS $*"; }
fail() { say "FAIL $*"; ok=0; }
now() { cut -d' ' -f1 /proc/uptime; }
ms() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%d", (b - a) * 1000 }'; }
prop() { systemctl show -p "$2" --value "$1"; }
# The unit's journal: the daemon's own lines and systemd's about the unit.
ujournal() { journalctl -b --no-pager -o cat -u "$U"; }
# Polls "$@" every 0.2 s for at most $1 seconds.
waitfor() {
    n=$(($1 * 5)); shift
    while ! "$@" >/dev/null 2>&1; do
        n=$((n - 1)); [ $n -le 0 ] && return 1; sleep 0.2
    done
}
# HEALTH through the C client, output in /tmp/health; with arguments, as
# util-linux's setpriv sets the user (by path: busybox's ash runs its own
# applets first, and busybox's setpriv cannot change users).
health() {
    if [ $# -gt 0 ]; then /usr/bin/setpriv "$@" gazesplat client health >/tmp/health 2>&1
    else gazesplat client health >/tmp/health 2>&1; fi
}
ready() { health && grep -q '^state READY' /tmp/health; }
journal_has() { ujournal | grep -q "$1"; }

say "checks start at $(now) s: PID 1 is $(cat /proc/1/comm), $(systemctl --version | head -1)"
[ "$(cat /proc/1/comm)" = systemd ] && pass "systemd is PID 1" || fail "PID 1 is $(cat /proc/1/comm)"
timeout 90 systemctl is-system-running --wait >/tmp/sysstate 2>&1
say "system $(cat /tmp/sysstate) at $(now) s; failed units: $(systemctl list-units --failed --plain --no-legend | cut -d' ' -f1 | tr '\n' ' ')"

# 0. docs/usage.md's post-install commands as written, less sudo (these
# checks run as root). apt installs the local .deb offline: the guest has no
# network and no package lists, so it must find every Depends installed (the
# host's dpkg status) and have nothing to fetch; without -y it would stop at
# a prompt (stdin is /dev/null) if it wanted any other package.
cd /usr/lib/gs-vm/build
deb=$(ls *.deb)
t0=$(now)
apt install ./$deb </dev/null >/tmp/apt 2>&1; rc=$?
sed 's/^/GS-VM: apt| /' /tmp/apt
st=$(dpkg-query -W -f '${Status} ${Version}' gazesplat 2>&1)
if [ $rc = 0 ] && grep -q '^0 upgraded, 1 newly installed, 0 to remove' /tmp/apt &&
   grep -q '^Need to get 0 B/' /tmp/apt &&
   [ "${st% *}" = "install ok installed" ]; then
    pass "apt install ./$deb: $st, nothing else installed or fetched ($(ms "$t0" "$(now)") ms)"
else
    fail "apt install ./$deb: rc $rc, dpkg status '$st'"
fi
cd /
en=$(systemctl is-enabled gazesplatd.socket 2>&1)
[ "$en" = disabled ] && [ "$(systemctl is-active gazesplatd.socket)" = inactive ] &&
    pass "the postinst enabled and started nothing: $S $en" || fail "after apt install: $S $en, $(systemctl is-active $S)"
# As an administrator would before starting it: the live keys appended to
# the configuration (a conffile) and the modules-load.d example copied, as
# its own comment says; systemd-modules-load then loads v4l2loopback with
# the package's modprobe.d options.
cat /usr/lib/gs-vm/live.conf >>/etc/gazesplat/gazesplatd.conf
cp /usr/share/doc/gazesplat/examples/gazesplat-v4l2loopback.modules-load.conf \
    /etc/modules-load.d/gazesplat-v4l2loopback.conf
systemctl restart systemd-modules-load.service ||
    fail "systemd-modules-load: $(systemctl status --no-pager systemd-modules-load.service 2>&1 | tail -5)"
# The postinst's systemd-sysusers made the group; the user is "gsmember".
gid=$(sed -n 's/^gazesplat:x:\([0-9]*\):.*/\1/p' /etc/group)
[ -n "$gid" ] && pass "the postinst's systemd-sysusers made group gazesplat (gid $gid)" ||
    fail "no gazesplat group in /etc/group"
USER=gsmember
usermod -aG gazesplat $USER >/tmp/usermod 2>&1; rc=$?
line=$(grep '^gazesplat:' /etc/group)
[ $rc = 0 ] && [ "${line##*:}" = gsmember ] && pass "usermod -aG gazesplat \$USER: $line" ||
    fail "usermod: rc $rc, $(cat /tmp/usermod), group line '$line'"
systemctl enable --now gazesplatd.socket >/tmp/enable 2>&1; rc=$?
links=$(ls /etc/systemd/system/*.wants/gazesplatd.socket 2>/dev/null | tr '\n' ' ')
[ $rc = 0 ] && [ -n "$links" ] && pass "systemctl enable --now gazesplatd.socket: $links" ||
    fail "systemctl enable --now: rc $rc, $(cat /tmp/enable), links '$links'"
# The postinst on an upgrade (here a reinstall of the same .deb) keeps the
# administrator's enablement; the socket keeps listening, the service stays
# down until a client comes (try-restart starts nothing).
t0=$(now)
(cd /usr/lib/gs-vm/build && apt install --reinstall ./$deb </dev/null >/tmp/apt 2>&1); rc=$?
en=$(systemctl is-enabled $S 2>&1)
if [ $rc = 0 ] && grep -q '^0 upgraded, 0 newly installed, 1 reinstalled' /tmp/apt && [ "$en" = enabled ] &&
   [ "$(systemctl is-active $S)" = active ]; then
    pass "apt install --reinstall: $S still $en and active ($(ms "$t0" "$(now)") ms)"
else
    sed 's/^/GS-VM: apt| /' /tmp/apt
    fail "after the reinstall: rc $rc, $S $en, $(systemctl is-active $S)"
fi
label=$(cat /sys/class/video4linux/video9/name 2>/dev/null)
[ "$label" = gazesplat ] && pass "modules-load.d + modprobe.d: /dev/video9 is '$label'" ||
    fail "no v4l2loopback /dev/video9 named gazesplat (got '$label'; $(ls /dev/video* 2>&1))"

# 1. Socket activation: listening, the service not started until a client comes.
[ "$(systemctl is-active $S)" = active ] && pass "$S active, listening on $(prop $S Listen)" ||
    fail "$S is $(systemctl is-active $S)"
st=$(systemctl is-active $U)
[ "$st" != active ] && pass "$U not started before the first connection ($st)" ||
    fail "$U already $st before any client"
docs=$(prop $U Documentation | tr -d '"')
missing=""
for d in $docs; do [ -f "${d#file:}" ] || missing="$missing $d"; done
[ -n "$docs" ] && [ -z "$missing" ] && pass "Documentation= names installed files: $docs" ||
    fail "Documentation='$docs', not installed:$missing"
perm=$(stat -c '%a %U:%G' $SOCK 2>&1)
[ "$perm" = "660 root:gazesplat" ] && pass "socket $SOCK is $perm" || fail "socket is '$perm'"
# The first client is the documented command, run by the user after logging
# in again (setpriv --init-groups: the groups from /etc/group, as login
# reads them). It is answered LOADING while the model loads (exit 1) and
# exits 0 once READY.
doc_health() {
    /usr/bin/setpriv --reuid=$USER --regid=$USER --init-groups \
        gazesplat client health --addr $SOCK >/tmp/health 2>&1
}
t0=$(now)
doc_health
t1=$(now)
first=$(sed -n 's/^state //p' /tmp/health)
if [ "$first" = READY ] || [ "$first" = LOADING ]; then
    pass "first client answered: HEALTH $first $(ms "$t0" "$t1") ms after connecting"
else
    fail "first HEALTH (as \$USER): $(cat /tmp/health)"
fi
if waitfor 120 doc_health && grep -q '^state READY' /tmp/health; then
    pass "gazesplat client health --addr $SOCK (as \$USER): exit 0, READY $(ms "$t0" "$(now)") ms after the first connection"
else
    fail "not READY within 120 s: $(cat /tmp/health)"
fi
start=$(prop $U ExecMainStartTimestampMonotonic)
t0us=$(awk -v a="$t0" 'BEGIN { printf "%d", a * 1000000 }')
[ "${start:-0}" -ge "$t0us" ] && pass "$U started by that connection (at $start us, client at $t0us us)" ||
    fail "$U started at ${start:-?} us, before the client (at $t0us us)"
pid=$(prop $U MainPID)

# The unit's resource controls and sandbox, as the kernel sees the process.
cg=/sys/fs/cgroup$(cut -d: -f3 /proc/$pid/cgroup)
nofile=$(sed -n 's/^Max open files *[0-9]* *\([0-9]*\).*/\1/p' /proc/$pid/limits)
res="nofile-hard $nofile memory.high $(cat $cg/memory.high 2>&1) cpu.weight $(cat $cg/cpu.weight 2>&1)"
[ "$res" = "nofile-hard 65536 memory.high 3221225472 cpu.weight 50" ] &&
    pass "LimitNOFILE/MemoryHigh/CPUWeight in force: $res ($cg)" || fail "resource controls: $res ($cg)"
st=$(grep -E '^(Uid|NoNewPrivs|Seccomp|CapEff):' /proc/$pid/status | tr -s '\t ' ' ' | tr '\n' ' ')
uid=$(echo "$st" | sed -n 's/.*Uid: \([0-9]*\).*/\1/p')
if echo "$st" | grep -q 'NoNewPrivs: 1 Seccomp: 2' && echo "$st" | grep -q 'CapEff: 0000000000000000' &&
   [ "${uid:-0}" -ge 61184 ] && [ "$uid" -le 65519 ]; then
    pass "sandbox in force: $st(DynamicUser range)"
else
    fail "sandbox: $st"
fi

# 2. The socket's group: a member is served, anyone else refused at connect.
if health --reuid=gsmember --regid=gsmember --init-groups && grep -q '^state READY' /tmp/health; then
    pass "gsmember (in group gazesplat) served"
else
    fail "gsmember refused: $(cat /tmp/health)"
fi
if ! health --reuid=gsother --regid=gsother --init-groups && grep -q 'Permission denied' /tmp/health; then
    pass "gsother (not in the group) refused: $(cat /tmp/health)"
else
    fail "gsother not refused with EACCES: $(cat /tmp/health)"
fi

# 3. The live pipeline under the sandbox: the loopback is written (DeviceAllow
# char-video4linux) and a USB hot-plug reaches libusb (AF_NETLINK, udev).
if waitfor 20 journal_has 'live: .* -> /dev/video9'; then
    pass "live pipeline started: $(ujournal | grep -m1 'live: .* -> /dev/video9')"
else
    fail "no live pipeline in the journal"
fi
journal_has 'hotplug off' && fail "$(ujournal | grep -m1 'hotplug off')"
fs=$((640 * 480 * 2))
timeout 20 v4l2-ctl -d /dev/video9 --stream-mmap --stream-count=2 --stream-to=/tmp/ph.yuv 2>/dev/null
size=$(wc -c < /tmp/ph.yuv 2>/dev/null || echo 0)
[ "$size" -eq $((2 * fs)) ] && pass "read 2 'no video' frames the daemon wrote to /dev/video9" ||
    fail "read $size bytes from /dev/video9 (want $((2 * fs)))"
say "HOTPLUG-READY"
if waitfor 30 journal_has 'live: USB 0627:0001 arrived'; then
    pass "hot-plug reached the daemon: $(ujournal | grep -m1 'live: USB 0627:0001 arrived')"
else
    fail "no hot-plug event in the daemon's journal ($(ls /sys/bus/usb/devices | tr '\n' ' '))"
fi

# 4. Reload: RELOADING=1 with MONOTONIC_USEC, then READY=1. systemd's debug
# log names every notification it gets (SIGRTMIN+22: debug, +23: back).
kill -s RTMIN+22 1 2>/dev/null || kill -56 1
sleep 0.5
tr=$(now)
systemctl reload $U; rc=$?
notes() { ujournal | grep 'Got notification message' | sed -n '/RELOADING=1/,$p'; }
reloaded() { notes | sed 1d | grep -q 'READY=1'; }
waitfor 60 reloaded
kill -s RTMIN+23 1 2>/dev/null || kill -57 1
first=$(notes | head -1)
ready=$(notes | sed 1d | grep -m1 'READY=1')
say "reload notifications: '${first#*message }' then '${ready#*message }'"
if [ $rc = 0 ] && echo "$first" | grep -q 'MONOTONIC_USEC=[0-9]' && [ -n "$ready" ]; then
    pass "systemctl reload: RELOADING=1 with MONOTONIC_USEC, READY=1 after it ($(ms "$tr" "$(now)") ms)"
else
    fail "reload: rc $rc, notifications '$first' / '$ready'"
fi
[ "$(prop $U MainPID)" = "$pid" ] && [ "$(systemctl is-active $U)" = active ] &&
    pass "reload kept pid $pid, $U active" ||
    fail "after reload: pid $(prop $U MainPID) (was $pid), $(systemctl is-active $U)"

# 5. Watchdog: WATCHDOG_USEC from WatchdogSec=, pings move WatchdogTimestamp,
# and a daemon that stops pinging (SIGSTOP) is killed and restarted.
wd=$(prop $U WatchdogUSec)
[ "$wd" = 30s ] && pass "WatchdogUSec=$wd" || fail "WatchdogUSec=$wd (unit says 30s)"
w0=$(prop $U WatchdogTimestampMonotonic)
moved() { [ "$(prop $U WatchdogTimestampMonotonic)" != "$w0" ]; }
if waitfor 25 moved; then
    pass "watchdog pinged: WatchdogTimestamp $w0 -> $(prop $U WatchdogTimestampMonotonic) us"
else
    fail "WatchdogTimestamp stayed at $w0 for 25 s"
fi
r0=$(prop $U NRestarts)
ts=$(now)
kill -STOP "$pid"
restarted() { [ "$(prop $U NRestarts)" -gt "$r0" ] && [ "$(prop $U MainPID)" != "$pid" ] &&
              [ "$(prop $U MainPID)" != 0 ]; }
if waitfor 90 restarted && journal_has 'Watchdog timeout'; then
    pass "SIGSTOP'd daemon: '$(ujournal | grep -m1 'Watchdog timeout')', restarted as pid $(prop $U MainPID) after $(ms "$ts" "$(now)") ms"
else
    fail "no watchdog restart: NRestarts $(prop $U NRestarts), pid $(prop $U MainPID)"
    kill -CONT "$pid" 2>/dev/null
fi
if waitfor 120 ready; then
    pass "the restarted daemon serves HEALTH READY"
else
    fail "after the restart: $(cat /tmp/health)"
fi

# 6. Stop: a clean exit within TimeoutStopSec (systemd would say Result=timeout).
tstop=$(now)
systemctl stop $U; rc=$?
res="$(prop $U Result) $(prop $U ExecMainCode) $(prop $U ExecMainStatus)"
# ExecMainCode 1 is CLD_EXITED.
if [ $rc = 0 ] && [ "$res" = "success 1 0" ] && [ "$(systemctl is-active $U)" = inactive ]; then
    pass "systemctl stop: exited 0 in $(ms "$tstop" "$(now)") ms (TimeoutStopSec $(prop $U TimeoutStopUSec))"
else
    fail "stop: rc $rc, Result/ExecMainCode/ExecMainStatus '$res', $(systemctl is-active $U)"
fi
[ "$(systemctl is-active $S)" = active ] && [ -S $SOCK ] && pass "$S still listening after the stop" ||
    fail "$S $(systemctl is-active $S) after the stop"

if [ $ok != 1 ]; then
    ujournal | tail -60 | sed 's/^/GS-VM: journal| /'
fi
say "done at $(now) s"
[ $ok = 1 ] && say "RESULT PASS" || say "RESULT FAIL"
sync
poweroff -f
