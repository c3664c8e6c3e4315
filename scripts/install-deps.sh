#!/usr/bin/env bash
# Installs every system dependency of gazesplat from Debian 12 packages.
# Used by scripts/demo.sh, scripts/test.sh and .ci/run. Idempotent: when
# everything is present it returns without touching apt.
set -euo pipefail

PACKAGES=(
  # build
  build-essential cmake ninja-build pkg-config git
  # libraries
  libopenblas-dev
  libopencv-core-dev libopencv-imgproc-dev
  # image codecs (lib/io): libpng and libjpeg-turbo, called directly
  libpng-dev libjpeg62-turbo-dev
  libusb-1.0-0-dev
  # augment: ETH-XGaze-style HDF5 files (lib/io/hdf5.c); h5py reads them in tests
  libhdf5-dev python3-h5py
  # daemon: BLAKE2b for subject keys and model ids
  libb2-dev
  libopencv-objdetect-dev libopencv-calib3d-dev
  # data: face cascades, the 68-point landmark model
  opencv-data libdlib-data
  # protocol: protobuf-c (C), protoc + python3-protobuf (Python client)
  libprotobuf-c-dev protobuf-c-compiler protobuf-compiler python3-protobuf
  # daemon tests: systemd-analyze, systemd-socket-activate
  systemd
  # the .deb (cpack): dpkg-deb, dpkg-shlibdeps and the file(1) it runs
  dpkg-dev file
  # the Python grid client (scripts/demo.sh): PNG reading and writing
  python3-pil
  # the Python package (clients/python): a venv to pip-install it into
  # without network, the build backend, and its type check
  python3-venv python3-setuptools python3-wheel mypy
  # scale-out tier (tests/scale): HAProxy in front of several daemons, and a
  # one-node Slurm (controller, node daemon, client commands, munge) for
  # augment as a job array; the tests start them as plain processes
  haproxy slurmctld slurmd slurm-client munge
  # tests: PyTorch reference, static analysis, libFuzzer
  python3 python3-numpy python3-torch
  cppcheck clang libclang-rt-14-dev
  # bench/io/bench_image: the former OpenCV decoder, side by side
  libopencv-imgcodecs-dev
  # face tests: dlib as the landmark reference, skimage's photos
  libdlib-dev python3-skimage
  # bench/eval/downstream_plot.py and experiments/eval/speed_table.py: the plots
  python3-matplotlib
  # VM tier (tests/vm): the emulator, the guest's shell and tools, depmod and
  # a kernel module build (the kernel itself is fetched by scripts/vm/prepare.sh
  # with apt-get download, never installed on the host)
  qemu-system-x86 busybox-static v4l-utils kmod
  # systemd VM tier (tests/vm/vm_systemd.py): the guest's userland is the
  # host's systemd plus procps' kill (the unit's ExecReload), util-linux's
  # setpriv (clients under other users) and mount
  procps util-linux mount
)
# npm fetches the face test photos (scripts/fetch-test-assets.sh). A node
# install from elsewhere may already bring its own npm, which Debian's
# package would conflict with.
if ! command -v npm >/dev/null 2>&1; then
  PACKAGES+=(npm)
fi

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

SUDO=
if [ "$(id -u)" -ne 0 ]; then
  SUDO=sudo
fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
