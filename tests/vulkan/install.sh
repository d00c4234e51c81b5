#!/bin/bash
# Makes sure this machine has a Vulkan device for the wgpu tests (tests/wgpu.rs): the Vulkan
# loader and a driver. Where there is none and we are root with apt-get, installs Debian's
# Vulkan loader and Mesa's software Vulkan driver, lavapipe (`mesa-vulkan-drivers`), which runs
# the same shaders as a GPU on the CPU. Exits non-zero, saying why, when no device can be had.
set -euo pipefail

# Not `ldconfig -p | grep -q`: under pipefail, grep's early exit on the first match can kill
# ldconfig with SIGPIPE mid-listing, and the pipeline then fails with the library present.
has_vulkan() {
    [[ $(ldconfig -p) == *libvulkan.so.1* ]] && {
        compgen -G '/usr/share/vulkan/icd.d/*.json' >/dev/null ||
            compgen -G '/etc/vulkan/icd.d/*.json' >/dev/null
    }
}

if has_vulkan; then
    exit 0
fi
if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null; then
    echo "no Vulkan loader and driver here, and installing them (libvulkan1, mesa-vulkan-drivers) needs root and apt-get" >&2
    exit 2
fi
log=$(mktemp)
install() {
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
        libvulkan1 mesa-vulkan-drivers >>"$log" 2>&1
}
# The package lists may be missing or stale; refresh them once if the first try fails.
if ! install && ! { apt-get update -q >>"$log" 2>&1 && install; }; then
    echo "apt-get could not install libvulkan1 and mesa-vulkan-drivers:" >&2
    tail -n 5 "$log" >&2
    rm -f "$log"
    exit 2
fi
rm -f "$log"
has_vulkan || { echo "still no Vulkan driver after the install" >&2; exit 2; }
